"""Research probes (``bench learn``, ``bench bandlimit``, ``bench guidance``): what the networks and the data allow,
answered in PSNR rather than in time."""
