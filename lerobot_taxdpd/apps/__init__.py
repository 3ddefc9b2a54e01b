"""Applications built on the package: the `taxdpd-demo` command and its synthetic two-slot task."""
