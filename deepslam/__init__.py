"""The deepslam command line. Thin: every subcommand lives in deepslam/commands/<name>.py."""
