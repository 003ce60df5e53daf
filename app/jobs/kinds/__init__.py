"""One module per job kind (thin adapters: load inputs, call the core, store results)."""
