"""Load deepslam's pytest plugin: the ``sim_sequence`` fixture and the trajectory assertions."""
pytest_plugins = ["deepslam.testing"]
