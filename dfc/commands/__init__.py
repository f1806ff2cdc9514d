"""One module per ``dfc`` command, each exposing a click command named ``command``."""
