from threedcal.cli import main

raise SystemExit(main())
