"""Paper-style reports from MLflow runs: ``python -m wdss.report --sweep NAME`` (or ``--parent RUN_ID``), or for
any runs: ``--runs ID [ID ...]`` or ``--experiment NAME [--filter "tags.model = 'joint_bilateral'"]``.

Reads the jobs of a sweep (the runs nested under its parent run), or the runs named, and writes, into
``outputs/reports/<sweep>/`` (``--name``; ``runs`` or the experiment's name for ad-hoc runs) and, for a sweep, as
artifacts of the parent run:

* ``table.md``: one compact table as the paper prints it: a row per configuration and data (the sweep's axes other
  than the seed, and the data root where the runs read several; named as the paper names its rows: ``SWT-db4``,
  ``No wavelet``, ``Bilinear (demod.)``), PSNR, SSIM,
  FLIP (and LPIPS when logged) and the temporal stability (the warping error's ratio to the target's own, best
  closest to 1, and the temporal PSNR; :mod:`wdss.training.temporal_metrics`) at the table's scale, each
  ``mean ± half-width`` of the 95% t-interval over the ``n`` seeds (``n/a`` with one seed), the best of each
  column in bold; a cell whose jobs failed says so instead of disappearing;
  below it, which of the paper's orderings hold at that scale (the sweep file's ``report.orderings``: the PSNR
  difference of each claimed pair, paired by seed, with its 95% t-interval);
* ``table.csv``: every metric at every scale and their average over scales, as mean, 95% half-width and n;
* ``tradeoff.png``: PSNR and FLIP against ms/frame and against GFLOPs, the Pareto front marked, with the
  training wall-clock per configuration beside it; log-x where the costs span decades, intervals only for n >= 3.
  The costs are the runs' own or, with ``--runtime runtime``, those of the runtime sweep (:file:`sweeps/runtime.yaml`:
  one process times every configuration); the axes name the device and the size, and the caption (also below the
  table) says how many processes timed the rows and which rows have no counted FLOPs (left out of that panel);
* ``qualitative.png``: the same crop of the first three test frames from every configuration and the target;
* ``frames.png``: PSNR against frame index over the first test sequence, a line per configuration (the mean over
  its seeds; each its own marker and dash, shifted sideways by a fraction of a frame), so that the drift of
  recurrent models shows.
"""
