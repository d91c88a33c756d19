"""deepslam: training deep SLAM on single frames, with a simulator that knows the answer.

One import name for the whole project: ``deepslam.core`` (SE3, cameras, trajectories, readers,
metrics), ``deepslam.scenes`` and ``deepslam.sim`` (the simulator), ``deepslam.gen`` (flow synthesis
from single frames, training shards), ``deepslam.vo`` (flow estimators, the flow -> 6DoF network),
``deepslam.slam`` (relocalization, pose graph, plug-in odometry), ``deepslam.studies`` (end-to-end
studies), ``deepslam.testing`` (the pytest plugin) and the command line, ``deepslam.cli`` with one thin
module per subcommand in ``deepslam.commands``.
"""
