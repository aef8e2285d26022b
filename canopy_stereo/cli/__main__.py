import sys

from canopy_stereo.cli import main

sys.exit(main())
