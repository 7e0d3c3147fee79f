"""``python -m wdss.data.check ROOT [--ckpt PATH] [--scales 2 3 4]``: what a folder of frames holds, before training.

For each sequence under ``ROOT`` (its sub-folders and zip files, or ``--sequences``): the layout (the authors'
``<H>P`` folders or DFASR's), the resolutions and frame counts, which buffers each resolution holds, what its
``sequence.json`` records (cameras, LR jitter, sampling conventions), and the value ranges of one frame (colour,
depth, normal length, motion), with the exposure that would bring its median luminance to middle grey, as wdss's
renders are pre-exposed (the metrics' tone map expects it; otherwise ``tonemap_exposure=auto``). With ``--ckpt``,
also what that model reads (its batch keys, hence buffers per role) and whether each sequence has it at every
scale asked for: natively (a ``<H/s>P`` folder) or point-sampled from HR. Exit status 0 when every sequence can
be read as asked, 2 otherwise (each problem on a line of its own).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from wdss.data.layouts import BUFFERS, OPTIONAL_BUFFERS, SceneError
from wdss.data.layouts import Sequence as Scene
from wdss.errors import UserError
from wdss.ops.sampling import scale_matches
from wdss.ops.tonemap import MIDDLE_GREY, luminance

__all__ = ["check_sequence", "main", "model_needs"]


def model_needs(ckpt: str | Path) -> tuple[list[str], dict[str, set[str]]]:
    """The batch keys a checkpoint's model reads at test time and the buffers they need per role (``hr``, ``lr``,
    ``prev``, ...), under the preprocessing it was trained with."""
    from wdss.checkpoint import read_checkpoint, training_preprocessing
    from wdss.data.dataset import Preprocessing, requirements
    from wdss.training.module import SuperResolutionModule

    read_checkpoint(ckpt)  # a file that is not a wdss checkpoint is named before torch opens it
    module = SuperResolutionModule.load_from_checkpoint(ckpt, map_location="cpu", weights_only=True)
    keys = list(module.test_inputs)
    prep = Preprocessing(**training_preprocessing(ckpt))
    return keys, requirements(keys, prep)


def _ranges(scene: Scene, frame: int) -> list[str]:
    """One line per buffer of ``frame`` at HR: its value range, and what a user would want to know of it."""
    present = [b for b in BUFFERS if scene.has(b, scene.hr, frame)]
    values = scene.read(frame, scene.hr, present, sanitize=True)
    lines = []
    for name in present:
        data = values[name]
        finite = np.isfinite(data)
        shown = data[finite] if finite.any() else np.zeros(1, np.float32)
        line = f"{name:<11} min {shown.min():.4g}  max {shown.max():.4g}"
        if name == "color":
            lum = luminance(np.clip(data, 0, None))
            lit = lum[lum > 0]
            median = float(np.median(lit)) if lit.size else 0.0
            line += f"  median luminance {median:.3g}"
            if median > 0:
                line += f" (x{MIDDLE_GREY / median:.3g} to middle grey {MIDDLE_GREY})"
        elif name == "normal":
            length = np.linalg.norm(data, axis=0)
            surface = length[length > 1e-3]  # zero: the sky
            if surface.size:
                off = np.mean(np.abs(surface - 1) > 0.05)
                line += f"  length {np.median(surface):.3f} median, {off:.1%} of surface pixels off unit length"
            line += f"; {1 - surface.size / length.size:.1%} zero (sky)"
        elif name == "motion":
            line += f"  |v| max {np.abs(data).max():.3g} HR pixels"
        lines.append(line)
    skipped = sum(scene.sanitized.values())
    if skipped:
        lines.append(f"non-finite values: {skipped} (replaced by 0 here; training refuses them unless sanitize)")
    return lines


def check_sequence(
    scene: Scene, scales: Iterable[float], needs: dict[str, set[str]] | None = None
) -> tuple[list[str], list[str]]:
    """What one sequence holds (lines to print) and what it lacks for ``needs`` at ``scales`` (problems)."""
    lines, problems = [], []
    width = scene.shape(scene.hr)[1]
    lines.append(f"layout {scene.layout.name}; HR {width}x{scene.hr}, {len(scene.frames)} frames")
    for height in scene.resolutions:
        frames = scene.frames_at(height)
        held = [b for b in BUFFERS if scene.has(b, height, frames[0])] if frames else []
        kind = "HR" if height == scene.hr else f"LR {scene.hr / height:.3g}x"
        lines.append(f"  {height}P ({kind}): {len(frames)} frames; {', '.join(held) or 'no buffers'}")
    if scene.source.has("sequence.json"):
        meta = json.loads(scene.source.read_bytes("sequence.json"))
        recorded = [k for k in ("seed", "exposure", "sampling", "noise", "fps") if k in meta]
        cameras = sum(scene.camera(f) is not None for f in scene.frames)
        jittered = any(scene.lr_jitter(f) != (0.0, 0.0) for f in scene.frames)
        lines.append(
            f"  sequence.json: {', '.join(recorded) or 'no settings'}; cameras for {cameras}/{len(scene.frames)} "
            f"frames; LR jitter {'per frame' if jittered else 'none'}"
        )
        sampling = meta.get("sampling")
        if isinstance(sampling, dict):
            lines.append("  sampling: " + ", ".join(f"{k} {v}" for k, v in sorted(sampling.items())))
    else:
        lines.append("  no sequence.json: no camera rotations (read unmirrored), LR assumed unjittered")
    middle = scene.frames[len(scene.frames) // 2]
    lines += [f"  frame {middle}: {line}" for line in _ranges(scene, middle)]
    needs = needs or {}
    for role, buffers in needs.items():
        hr = role in ("hr", "prev", "prev2")
        for buffer in sorted(buffers):
            if hr and buffer not in OPTIONAL_BUFFERS and not scene.has(buffer, scene.hr):
                problems.append(f"{scene.name}: the model reads {buffer} ({role}) and {scene.hr}P has none")
    low = needs.get("lr", set()) | needs.get("prev_lr", set())
    for scale in scales:
        native = next((h for h in scene.resolutions[1:] if scale_matches(scene.hr, h, scale)), None)
        if native is None:
            if scale == int(scale) and (scene.hr % int(scale) or width % int(scale)):
                problems.append(f"{scene.name}: {width}x{scene.hr} is not divisible by scale {scale:g}")
            lines.append(f"  scale {scale:g}: no native LR folder; LR point-sampled from HR (data.lr_source=auto)")
            missing = [b for b in sorted(low) if b not in OPTIONAL_BUFFERS and not scene.has(b, scene.hr)]
        else:
            lines.append(f"  scale {scale:g}: native LR {native}P")
            missing = [b for b in sorted(low) if b not in OPTIONAL_BUFFERS and not scene.has(b, native)]
        problems += [
            f"{scene.name}: the model reads LR {b} at scale {scale:g}, which "
            + (f"{native}P lacks (data.lr_source=point reads it from HR)" if native else f"{scene.hr}P lacks")
            for b in missing
        ]
    return lines, problems


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m wdss.data.check", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("root", help="a folder of sequences (each a sub-folder or zip in the unreal or dfasr layout)")
    parser.add_argument("--sequences", nargs="+", default=None, help="only these (default: every one under root)")
    parser.add_argument("--layout", default="auto", help="auto | unreal | dfasr")
    parser.add_argument("--ckpt", default=None, help="a wdss checkpoint: check what its model reads")
    parser.add_argument("--scales", nargs="+", type=float, default=[2.0, 3.0, 4.0], help="scales to check")
    args = parser.parse_args(argv)
    root = Path(args.root)
    problems: list[str] = []
    try:
        if not root.is_dir():
            raise SceneError(f"{root} is not a folder")
        needs = None
        if args.ckpt:
            keys, needs = model_needs(args.ckpt)
            wanted = {role: sorted(b) for role, b in needs.items() if b}
            print(
                f"{args.ckpt} reads {', '.join(keys)}: " + "; ".join(f"{r} {', '.join(b)}" for r, b in wanted.items())
            )
        names = args.sequences
        if names is None:
            names = sorted(p.name.removesuffix(".zip") for p in root.iterdir() if p.is_dir() or p.suffix == ".zip")
        if not names:
            raise SceneError(f"{root} holds no sequence folders or zip files")
        for name in names:
            path = root / name if (root / name).exists() else root / f"{name}.zip"
            try:
                scene = Scene(path, args.layout)
                lines, found = check_sequence(scene, args.scales, needs)
            except UserError as err:
                print(f"{name}: unreadable")
                problems.append(str(err))
                continue
            print(f"{name}: " + lines[0])
            print("\n".join(lines[1:]))
            problems += found
    except UserError as err:  # a checkpoint, a folder or an EXR file that cannot be read
        print(f"wdss.data.check: {err}", file=sys.stderr)
        return 2
    if problems:
        print(f"\n{len(problems)} problem(s):", file=sys.stderr)
        for problem in problems:
            print(f"  {problem}", file=sys.stderr)
        return 2
    print(f"\n{len(names)} sequence(s) readable" + (" with everything the model reads" if needs else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
