import sys

from deepslam.cli import main

sys.exit(main())
