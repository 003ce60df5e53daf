"""Live machines: the connected backends by id, where a head is, materials and dispense
profiles."""
