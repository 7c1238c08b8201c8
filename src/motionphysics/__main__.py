import sys

from motionphysics.cli import main

sys.exit(main())
