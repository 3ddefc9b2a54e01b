"""`python -m lerobot_taxdpd.sim.cloth {generate,eval} --task cloth_hang ...`: the same command line as
`python -m lerobot_taxdpd.sim` (see `lerobot_taxdpd.sim.cli`)."""

from lerobot_taxdpd.sim.cli import main

raise SystemExit(main())
