"""Monte Carlo localization as composable parts (in the spirit of Beluga), one file per part.

- `filter.py`: the particle filter loop (ROS 1 amcl's laserReceived) and its small
  `FilterParams`; it holds the parts below, each behind a small `typing.Protocol`;
- `motion.py`: odometry motion models (`diff`, `diff-corrected`), registered by ROS name;
- `sensor_models.py`: laser models (`likelihood_field`, `likelihood_field_prob`, `beam`), each
  with its own parameters (ROS's `laser_*` keys);
- `proposals.py`: where particles that do not descend from the filter's come from (global
  initialisation, recovery), and `PriorWeights`, how those are weighted;
- `resampler.py`: KLD resampling with injection; `estimator.py`: the heaviest cluster's mean;
- `trigger.py`: when to update, resample and publish (update_min_d / _a, resample_interval);
- `config.py`: a flat ROS-named config (conf/localizer/amcl.yaml) mapped onto the parts.
The compiled kernels stay in localize/ (likelihood_field.py, likelihood_field_prob.py,
beam_model.py, kld_resampling.py, clustering.py). The hybrid (localize/hybrid.py) is a
proposal and its importance weights plugged into the same filter.
"""
