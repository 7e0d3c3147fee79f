"""``bench render`` and ``bench noise``: the quality of rendered frames (sample counts, the targets' own noise)."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path

import torch
from rich.table import Table


def bench_render(
    seeds: Sequence[int], frame: int, size: tuple[int, int], samples: Sequence[int], reference: int
) -> Table:
    """Render quality: colour at each sample count (+ OpenImageDenoise, as datasets are rendered) against a
    ``reference``-sample render of the same frame without denoising, PSNR after the metric's tone map at the
    sequence's auto exposure, and seconds per frame. Needs the ``render`` extra."""
    import numpy as np

    from wdss.ops.tonemap import hable
    from wdss.render.blender import BlenderScene
    from wdss.render.exposure import auto_exposure
    from wdss.render.spec import random_scene

    width, height = size
    table = Table(title=f"render: {width}x{height}, frame {frame}, against {reference} spp without denoising")
    for column in ("seed", "spp", "s/frame", "PSNR (dB)", "high-freq. energy / reference"):
        table.add_column(column, justify="right")
    for seed in seeds:
        scene = BlenderScene(random_scene(seed), samples=reference, denoise=True, filter_width=0.01)
        exposure = auto_exposure(scene.render(0, width, height, samples=8)["Combined"][:3])
        # The reference is not denoised: a denoiser that smears texture would smear the reference alike and hide it.
        scene.denoise = False
        start = time.perf_counter()
        ref = torch.from_numpy(scene.render(frame, width, height)["Combined"][None, :3] * exposure)
        ref_seconds = time.perf_counter() - start
        scene.denoise = True
        ref_ldr = hable(ref)

        def detail(x: torch.Tensor) -> float:  # energy of the Laplacian: texture a denoiser smears is lost here
            lap = x[..., 1:-1, 1:-1] * 4 - x[..., :-2, 1:-1] - x[..., 2:, 1:-1] - x[..., 1:-1, :-2] - x[..., 1:-1, 2:]
            return float((lap**2).mean())

        for spp in samples:
            start = time.perf_counter()
            color = torch.from_numpy(scene.render(frame, width, height, samples=spp)["Combined"][None, :3] * exposure)
            seconds = time.perf_counter() - start
            mse = float(((hable(color) - ref_ldr) ** 2).mean())
            psnr = -10 * np.log10(max(mse, 1e-12))
            ratio = detail(hable(color)) / max(detail(ref_ldr), 1e-12)
            table.add_row(str(seed), str(spp), f"{seconds:.1f}", f"{psnr:.2f}", f"{ratio:.3f}")
        table.add_row(str(seed), f"{reference} (ref)", f"{ref_seconds:.1f}", "-", "1.000")
    return table


def bench_noise(folders: Sequence[str], frames: Sequence[int] | None, noise_seed: int, record: bool) -> Table:
    """The targets' own noise of rendered procedural sequences (:func:`wdss.render.noise.measure_noise`: each HR
    frame rendered again with another Cycles seed; the ceiling every PSNR measured on these targets lies under).
    ``record`` writes it into each sequence's ``sequence.json`` (``noise``). Needs the ``render`` extra."""
    import json

    from wdss.data.layouts import Sequence as Frames
    from wdss.render.blender import BlenderScene
    from wdss.render.noise import measure_noise
    from wdss.render.spec import SceneSpec

    table = Table(title=f"targets' noise: re-rendered with Cycles seed offset {noise_seed}, Hable at exposure 10")
    for column in ("sequence", "frames", "PSNR target vs re-render (dB)", "ceiling (dB)", "s/frame"):
        table.add_column(column, justify="right")
    for folder in map(Path, folders):
        sidecar = folder / "sequence.json"
        meta = json.loads(sidecar.read_text()) if sidecar.exists() else {}
        settings = meta.get("settings", {})
        if "things" not in (meta.get("scene") or {}) or not meta.get("exposure"):
            raise SystemExit(f"bench noise: {sidecar} is not a procedural sequence wdss rendered (no scene spec)")
        scene = BlenderScene(
            SceneSpec.from_dict(meta["scene"]),
            samples=settings["samples"],
            denoise=settings["denoise"],
            filter_width=settings["filter_width"],
        )
        noise = measure_noise(scene, folder, meta["exposure"], frames or Frames(folder).frames, noise_seed)
        ceiling = noise["ceiling_psnr_db"]
        table.add_row(
            folder.name,
            str(len(noise["frames"])),
            f"{ceiling - 10 * math.log10(2.0):.2f}",
            f"{ceiling:.2f}",
            f"{noise['seconds_per_frame']:.1f}",
        )
        if record:
            meta["noise"] = noise
            sidecar.write_text(json.dumps(meta, indent=1))
    return table
