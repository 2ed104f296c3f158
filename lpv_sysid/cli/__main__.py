import sys

from lpv_sysid.cli.main import main

sys.exit(main())
