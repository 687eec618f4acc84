from cablesvc.cli.main import main

raise SystemExit(main())
