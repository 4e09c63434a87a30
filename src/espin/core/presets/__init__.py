"""Built-in run configurations (TOML files); ``plla`` is the paper's Tables 2 and 3, ``plla-bonded`` the
same mat with fused crossings and free lateral edges (docs/mechanics.md, "Fused crossings")."""
