"""Mocks that are real backends: the simulated building (:mod:`mocks.world`) and the virtual P3-AT
(:mod:`mocks.p3at`), which speaks ARCOS over a pseudo-terminal or TCP."""
