"""One module per ``nao-skin`` command (see :mod:`nao_skin.cli`)."""
