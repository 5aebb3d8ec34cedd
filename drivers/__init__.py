"""Hardware drivers: ARCOS (Pioneer P3-AT) and the IIDC stereo head. Pure protocol modules plus thin I/O."""
