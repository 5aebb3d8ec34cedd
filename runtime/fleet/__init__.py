"""A fleet on its own machines: each robot one process, maps exchanged over Zenoh (see docs/fleet.md).

``mapwire`` is the wire format (pure), ``zenoh_exchange`` the only module that imports zenoh, ``fusion_node``
the live fusion node, ``processes`` the multi-process demo.
"""
