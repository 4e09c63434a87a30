"""Built-in run configurations (TOML files); ``plla`` is the paper's Tables 2 and 3."""
