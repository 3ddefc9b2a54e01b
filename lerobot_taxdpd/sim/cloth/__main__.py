"""`python -m lerobot_taxdpd.sim.cloth {generate,eval} --task cloth_hang ...`"""

from lerobot_taxdpd.sim.cloth.cli import main

raise SystemExit(main())
