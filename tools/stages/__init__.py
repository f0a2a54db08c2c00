"""Motion stages of the lab bench: one Stage interface, Thorlabs APT and Newport CONEX drivers, and byte-protocol simulators."""
