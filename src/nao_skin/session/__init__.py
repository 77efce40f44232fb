"""A record session: which nodes it runs, with which parameters, checked before any starts."""
