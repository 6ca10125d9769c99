"""Monte Carlo localization as composable parts (in the spirit of Beluga), one file per part.

- `filter.py`: the particle filter loop (ROS 1 amcl's laserReceived) and its small
  `FilterParams`; it holds the parts below, each behind a small `typing.Protocol`;
- `motion.py`: odometry motion models (`diff`, `diff-corrected`), registered by ROS name;
- `sensor_models.py`: laser models (`likelihood_field`, `likelihood_field_prob`, `beam`), each
  with its own parameters (ROS's `laser_*` keys);
- `proposals.py`: where particles that do not descend from the filter's come from (global
  initialisation, recovery, mixing), and `PriorWeights`, how those are weighted;
- `mixing.py`: how many particles come from the proposal at an update (amcl: none);
- `parts.py`: the proposal, mixing and weighting types a config names (`type`), registered;
- `resampler.py`: KLD or fixed-size resampling with injection, selective resampling around it;
- `estimator.py`: the heaviest cluster's mean, or the weighted mean;
- `trigger.py`: when to update (on motion, every scan), resample and publish;
- `averages.py`: the w_slow / w_fast likelihood averages (recovery, adaptive mixing);
- `config.py`: a config's `filter`, `motion` and `sensor` sections (ROS's names) mapped onto
  the parts, and the filter built from them.
The compiled kernels stay in localize/ (likelihood_field.py, likelihood_field_prob.py,
beam_model.py, kld_resampling.py, clustering.py). The hybrid (localize/hybrid.py) is a
proposal, a mixing and importance weights plugged into the same filter.
"""
