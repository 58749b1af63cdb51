from eigenscope.cli import main

raise SystemExit(main())
