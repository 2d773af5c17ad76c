import sys

from crowdcam.cli import main

sys.exit(main())
