"""PNG figures (matplotlib, Agg backend): one module per subject."""
