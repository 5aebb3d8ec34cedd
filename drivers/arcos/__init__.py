"""Pioneer P3-AT over ARCOS: pure protocol modules (``commands``, ``codec``, ``params``) and the I/O driver."""
