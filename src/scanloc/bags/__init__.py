"""ROS bags in and out, no ROS installation needed (rosbags): a scanloc run exported as a ROS 1
or ROS 2 bag (write.py), a robot's bag made into a scanloc run (read.py) and its laser into a
conf/sensor file (describe.py), and any localizer's estimate stream scored on a run like
scanloc's own (score.py). docs/bags.md has the commands."""
