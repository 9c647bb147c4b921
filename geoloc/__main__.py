import sys

from geoloc.cli import main

sys.exit(main())
