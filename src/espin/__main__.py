"""``python -m espin``: the ``espin`` command line."""

from espin.cli import app

app(prog_name="espin")
