"""A benchmark run: inputs resolved and checked, the jobs (model × ISO × seed, noise on noise),
each network trained and scored (resumable from ``--state``), the results gathered."""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import noisecal

from .data import eval_pairs, load_captures, load_clean, load_eval, load_float_clean
from .errors import BenchError
from .estimate import DEFAULT_ESTIMATE, estimates_for, parse_estimates
from .headroom import headroom
from .layout import normalise
from .models import RENOISE_METHODS, ModelSpec, Pairs, interpolation_notes, make_pairs, parse_model
from .network import _torch
from .scenes import generate_clean, generate_tiles, parse_levels
from .scoring import controls, evaluate, noise_rms, score_input, summary
from .training import batch_plan, train_one


# The rows whose noisy training images are real captures (or made from them), drawn about the
# scene before its rounding: with float clean training images (data.load_float_clean) that is their target.
CAPTURED = ("oracle", "renoise")


def training_targets(kind: str, cleans_norm: list, floats_norm: list | None) -> list:
    """The clean images a row of ``kind`` is trained to return: the float clean images
    (``floats_norm``, when the training folder gives them) for the rows trained on real captures
    (:data:`CAPTURED`), whose noise is about them; the whole-DN ones (``cleans_norm``) for every
    synthetic row, whose noise is drawn about the image it is handed."""
    return floats_norm if floats_norm is not None and kind in CAPTURED else cleans_norm


def _config_key(cfg: dict) -> str:
    return hashlib.blake2b(json.dumps(cfg, sort_keys=True).encode(), digest_size=8).hexdigest()


def _floats(text: str | None, flag: str, count: int) -> list[float] | None:
    """``--flag A,B,…``: ``count`` numbers ≥ 0 (``count`` 1: one or more)."""
    if text is None:
        return None
    try:
        v = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        v = []
    if not v or (count > 1 and len(v) != count) or min(v) < 0:
        want = "one or more numbers ≥ 0" if count == 1 else f"{count} numbers ≥ 0"
        raise BenchError(f"{flag} {text!r}: give {want}, separated by commas")
    return v


def networks_trained(jobs: list, seeds: int) -> int:
    """The networks a run trains: one per (model, ISO) job and seed, and the denoiser that
    estimates the clean image for noise on noise (a row with the ``denoiser`` estimate): one more
    network of the same steps, trained once (unless every row is resumed from ``--state``)."""
    return len(jobs) * seeds + int(any(s.kind == "renoise" and s.estimate == "denoiser" for s, _ in jobs))


def steps_for_minutes(minutes: float, per_step: float, networks: int, at_most: int | None = None) -> int:
    """The steps per network that fit ``networks`` networks (every one the run trains, the clean
    estimate's denoiser included) into 85 % of ``minutes`` at ``per_step`` seconds a step; at
    least 20, and at most ``at_most`` (``--steps`` when given)."""
    fit = int(minutes * 60 * 0.85 / (networks * per_step))
    return max(20, fit if at_most is None else min(at_most, fit))


def run(args: argparse.Namespace) -> dict:
    t0 = time.time()
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr, flush=True))
    if args.set:
        root = Path(args.set)
        args.eval = args.eval or root / "eval"
        if not args.train and not args.generate:
            args.train = root / "train" / "clean"
        if not args.captures and (root / "train" / "captures").is_dir():
            args.captures = root / "train" / "captures"
    if not args.pack:
        raise BenchError("--pack is needed: the calibrated pack whose noise is benchmarked")
    if not args.eval:
        raise BenchError("--eval DIR is needed (or --set DIR): per scene a base-ISO burst and frames at target ISOs")
    pack = noisecal.Pack.load(args.pack)
    layout = pack.layout
    scenes = load_eval(Path(args.eval), pack)
    eval_isos = sorted({i for s in scenes for i in s.frames})
    try:
        isos = eval_isos if not args.isos else [int(i) for i in args.isos.split(",") if i.strip()]
    except ValueError:
        raise BenchError(f"--isos {args.isos!r}: give whole ISOs separated by commas, e.g. 400,1600") from None
    missing = [i for i in isos if i not in eval_isos]
    if missing:
        raise BenchError(f"--isos {missing}: the evaluation set has frames at ISOs {eval_isos} only")
    floats = None  # the clean training images before rounding (load_float_clean), when given
    if args.train:
        names, cleans = load_clean(Path(args.train), pack)
        floats = load_float_clean(Path(args.train), names, cleans)
    else:
        n = args.generate or 16
        h, w = (scenes[0].clean.shape[0] // 2) * 2, (scenes[0].clean.shape[1] // 2) * 2
        names = [f"gen{i:03}" for i in range(n)]
        levels = parse_levels(args.generate_levels, layout)
        if getattr(args, "tiles", None):
            top = float(layout["white"]) - max(float(b) for b in layout["black"])
            ladder = _floats(getattr(args, "tile_ladder", None), "--tile-ladder", 1)
            texture = _floats(getattr(args, "tile_texture", None), "--tile-texture", 2) or [0.0, 0.0]
            cleans = generate_tiles(
                n, h, w, layout, args.data_seed, args.tiles, args.tile_blur, levels or (0.0, top), ladder, (texture[0], texture[1])
            )
        else:
            cleans = generate_clean(n, h, w, layout, args.data_seed, args.mono, levels)
    captures = load_captures(Path(args.captures), names, pack) if args.captures else {}
    shapes = {c.shape for c in cleans}
    if len(shapes) != 1:
        raise BenchError(f"--train: clean images of different sizes {sorted(shapes)}: use one size (crops are drawn from each)")
    if args.realizations:
        realizations = args.realizations
    elif captures:
        realizations = min(len(v) for v in captures.values())
    else:
        realizations = 4
    packs = {args.pack: pack}  # a model naming the main pack's file does not load it again
    specs = [parse_model(m, args.plain_pack) for m in args.models.split(",") if m.strip()]
    for c in args.components or []:
        specs.append(ModelSpec(f"noisecal:{c}", "noisecal", c))
    for s in specs:
        if s.pack_path and s.pack_path not in packs:
            packs[s.pack_path] = noisecal.Pack.load(s.pack_path)
        if s.kind == "oracle" and not captures:
            raise BenchError(
                "model oracle trains on the sensor's own noise: give --captures (real captures of the training scenes, "
                "<clean stem>_*.dng; `noisecal simulate --bench DIR` writes them) or drop oracle from --models"
            )
    labels = [s.label for s in specs]
    if len(set(labels)) != len(labels):
        raise BenchError(f"--models: labels repeat in {labels}: name them LABEL=MODEL")
    jobs = [(s, iso) for s in specs for iso in isos]
    if args.renoise_from is not None:
        a, b = args.renoise_from, args.renoise_to
        if b is None or b not in eval_isos or not captures:
            raise BenchError(
                "noise on noise needs --renoise-to B at an ISO of the evaluation set and --captures holding real ISO-A "
                "captures of the training scenes"
            )
        methods = [m.strip().lower() for m in getattr(args, "renoise_methods", ",".join(RENOISE_METHODS)).split(",") if m.strip()]
        unknown = [m for m in methods if m not in RENOISE_METHODS]
        if unknown or not methods:
            raise BenchError(f"--renoise-methods {unknown or '(none)'}: use some of {', '.join(RENOISE_METHODS)}")
        kinds = parse_estimates(getattr(args, "renoise_estimate", DEFAULT_ESTIMATE))
        for m in methods:
            # The naive method picks its bins by the noisy input itself: no estimate.
            for e in [None] if m == "naive" else kinds:
                tag = "" if e in (None, DEFAULT_ESTIMATE) else f"[{e}]"
                jobs.append((ModelSpec(f"{m}{tag} {a}→{b}", "renoise", method=m, from_iso=a, estimate=e), b))
        if not any(s.kind == "oracle" for s in specs):
            jobs.append((ModelSpec(f"real {b}", "oracle"), b))
    cleans_norm = [normalise(c, layout["black"], layout["white"]) for c in cleans]
    # The target of the rows trained on real captures (CAPTURED): the float clean image the captures
    # were drawn about, when the training folder gives it; every other row's noise is drawn about
    # the whole-DN image it is handed, so that is its target.
    floats_norm = None if floats is None else [normalise(c, layout["black"], layout["white"]) for c in floats]

    def target_of(spec: ModelSpec) -> list:
        return training_targets(spec.kind, cleans_norm, floats_norm)
    seeds = list(range(args.seed, args.seed + args.seeds))
    torch = _torch()
    device = torch.device(args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    steps = args.steps
    n_nets = len(jobs) * len(seeds)
    extra = networks_trained(jobs, len(seeds)) - n_nets
    if args.minutes:
        probe = batch_plan(0, 6, args.batch, len(cleans), realizations, cleans[0].shape, args.crop)
        dummy = Pairs([[c] * realizations for c in cleans])
        train_one(dummy, cleans_norm, layout, probe[:2], args.crop, args.width, 0, device, args.lr)  # warm-up
        t = time.time()
        train_one(dummy, cleans_norm, layout, probe, args.crop, args.width, 0, device, args.lr)
        per_step = (time.time() - t) / len(probe)
        steps = steps_for_minutes(args.minutes, per_step, n_nets + extra, steps if args.steps_given else None)
        say(
            f"--minutes {args.minutes}: {per_step * 1000:.1f} ms per step → {steps} steps per network ({n_nets} networks"
            + (" and the clean estimate's denoiser)" if extra else ")")
        )
    cfg = {
        # Every pack a model reads, by its file's bytes: a pack changed on disk is not resumed.
        "packs": {p: hashlib.blake2b(Path(p).read_bytes(), digest_size=8).hexdigest() for p in sorted(packs)},
        "eval": str(Path(args.eval).resolve()),
        "train": str(Path(args.train).resolve())
        if args.train
        else f"generated:{len(cleans)}"
        + (":mono" if args.mono else "")
        + (f":{args.generate_levels}" if args.generate_levels else "")
        + (f":tiles:{args.tiles}:{args.tile_blur:g}" if getattr(args, "tiles", None) else "")
        + (f":ladder:{args.tile_ladder}" if getattr(args, "tile_ladder", None) else "")
        + (f":texture:{args.tile_texture}" if getattr(args, "tile_texture", None) else ""),
        "steps": steps,
        "batch": args.batch,
        "crop": args.crop,
        "width": args.width,
        "lr": args.lr,
        "realizations": realizations,
        "data_seed": args.data_seed,
        "device": args.device,
    }
    if floats is not None:  # absent without .npy clean images, so earlier runs' keys stay valid
        cfg["train_float_clean"] = True
    if args.input_scale != 1.0:  # absent at 1, so the keys (and --state files) of earlier runs stay valid
        cfg["input_scale"] = args.input_scale
    loss, highpass = getattr(args, "loss", "l1"), getattr(args, "highpass", False)
    if loss != "l1":  # absent at the defaults, as input_scale
        cfg["loss"] = loss
    if highpass:
        cfg["highpass"] = "eval-rms"
    # The parametric baselines' pairs carry the gain shift (models.at_target_brightness): rows
    # stored before it are not resumed.
    cfg["baselines_at_target_brightness"] = True
    cfg["init"] = "he-identity"  # network.make_net's initialisation: earlier networks are not resumed
    key = _config_key(cfg)
    state = Path(args.state) if args.state else None
    if state:
        state.mkdir(parents=True, exist_ok=True)
    prepared: dict[int, list] = {}

    def eval_at(iso: int) -> list:
        if iso not in prepared:
            prepared[iso] = eval_pairs(scenes, iso, layout)
        return prepared[iso]

    def flat_at(iso: int) -> float:
        """The flat-region tolerance at ``iso`` (:func:`noisecal.bench.metrics.region_masks`): the
        RMS of the real evaluation noise there, so a flat region is one whose clean image varies
        less than the noise over a 5×5 packed window."""
        return noise_rms(eval_at(iso))

    def sigma_at(iso: int) -> float | None:
        """--highpass: the network's noise unit at ``iso``, the RMS of the real evaluation noise
        there (normalised): one scale for every model, none of them its own."""
        return noise_rms(eval_at(iso)) if highpass else None

    denoiser: dict = {}

    def train_denoiser():
        """The source-ISO denoiser of noise on noise (the paper's clean estimate): the pack's
        synthetic noise at ISO A on the clean training images, the same steps and network as every
        row, seeded by the data seed (not a training seed: a run split over several processes, one
        --seed each, gets the same estimate); trained once."""
        if "net" not in denoiser:
            a = args.renoise_from
            say(f"clean estimate for noise on noise: training a denoiser on noisecal's ISO {a} noise")
            spec = ModelSpec(f"noisecal {a} (estimate)", "noisecal")
            p = make_pairs(spec, a, cleans, realizations, pack, captures, args.data_seed, packs)
            seed = args.data_seed
            plan = batch_plan(seed, steps, args.batch, len(cleans), realizations, cleans[0].shape, args.crop)
            # The same loss; no --highpass (its unit is the evaluation noise at a target ISO, not at A).
            denoiser["net"] = train_one(p, cleans_norm, layout, plan, args.crop, args.width, seed, device, args.lr, None, args.input_scale, loss)
        return denoiser["net"]

    estimates: dict = {}

    def estimates_of(kind):
        if kind not in estimates:
            a = args.renoise_from
            frames = [captures.get((j, a), [])[:realizations] for j in range(len(cleans))]
            estimates[kind] = estimates_for(kind, frames, cleans, train_denoiser, layout, device)
        return estimates[kind]

    results = []
    done = 0
    for spec, iso in jobs:
        pairs = None
        for seed in seeds:
            done += 1
            tag = f"[{done}/{n_nets}] {spec.label} ISO {iso} seed {seed}"
            fname = None
            if state:
                job_id = f"{spec}|{iso}|{seed}" + (f"|estimate={spec.estimate}" if spec.estimate else "")
                job_id += f"|factor={spec.factor!r}" if spec.factor is not None else ""
                fname = state / f"{key}-{hashlib.blake2b(job_id.encode(), digest_size=6).hexdigest()}.json"
                if fname.exists():
                    results.append(json.loads(fname.read_text()))
                    say(f"{tag}: resumed from {fname.name}")
                    continue
            if pairs is None:
                est = estimates_of(spec.estimate) if spec.kind == "renoise" and spec.estimate else None
                pairs = make_pairs(spec, iso, cleans, realizations, pack, captures, args.data_seed, packs, est)
            plan = batch_plan(seed, steps, args.batch, len(cleans), realizations, cleans[0].shape, args.crop)
            ts = time.time()

            def progress(s, n, loss, tag=tag, ts=ts):
                tty = sys.stderr.isatty()
                if not args.quiet and (s == n or s % max(1, n // (20 if tty else 4)) == 0):
                    end = "\n" if s == n or not tty else "\r"
                    print(f"{tag}: step {s}/{n} loss {loss:.4f} {time.time() - ts:.0f} s", end=end, file=sys.stderr, flush=True)

            net = train_one(
                pairs, target_of(spec), layout, plan, args.crop, args.width, seed, device, args.lr, progress, args.input_scale,
                loss, sigma_at(iso),
            )  # fmt: skip
            r = {"model": spec.label, "kind": spec.kind, "iso": iso, "seed": seed, **evaluate(net, eval_at(iso), device, flat_at(iso))}
            if spec.factor is not None:
                r["factor"] = spec.factor
            r["train_seconds"] = time.time() - ts
            results.append(r)
            if fname:
                fname.write_text(json.dumps(r))
    inputs = {iso: score_input(eval_at(iso), flat_at(iso)) for iso in sorted({iso for _, iso in jobs})}
    out: dict[str, Any] = {
        "config": cfg,
        "input": inputs,
        "isos": isos,
        "calibrated_isos": pack.calibrated_isos,
        "seeds": seeds,
        "networks": results,
        "summary": summary(results),
        "wall_seconds": time.time() - t0,
    }
    out["controls"] = controls(out["summary"])
    # How much of the evaluation noise a filter removes (no network; half a DN the flat test).
    tol = 0.5 / (float(layout["white"]) - max(float(b) for b in layout["black"]))
    out["headroom"] = {iso: headroom(eval_at(iso), tol) for iso in inputs}
    out["notes"] = interpolation_notes(specs, isos, pack, packs)
    return out
