import sys

from rsmt_cli.main import main

sys.exit(main())
