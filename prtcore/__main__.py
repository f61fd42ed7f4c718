from prtcore.cli import main

raise SystemExit(main())
