"""Sub-commands of ``p3at``: one module per area, each with ``register(subparsers)``."""
