"""`python -m lerobot_taxdpd.sim {generate,eval} --task T ...` (see `lerobot_taxdpd.sim.cli`)."""

from lerobot_taxdpd.sim.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
