"""``python -m disent.bench models`` and ``time_to_accuracy``.

``models``: for each model, its FLOPs per image (torch's ``FlopCounterMode``) for a forward
pass and for a whole training step (generator and EBGAN discriminator, forward and backward),
then training images/s with and without the discriminator and inference images/s at batch
1, 64 and 256, each also as a fraction of the fp32 matmul peak measured in the same run
(``achieved FLOP/s / peak``).  Training with D is timed doing its whole work (every generated
image inside D's margin, ``FULL_WORK_MARGIN``) and, as ``train_past_margin``, with every generated
image past the margin, where D's loss leaves the generated batch out (most steps of the default
runs).  Every figure is the median of several rounds; the machine is shared, so each rate's rounds
alternate with rounds of the peak's matmul and the rate is stated against the median of those
(``<rate>_peak_gflops``); ``peak_gflops`` is the median of all of them.  ``implicit_vs_explicit``
compares the two models' images/s timed in alternating rounds.  The data
loader (``SynthFaces.get_batch`` on fresh indices) is timed alone at the training batch
size, to show it outruns training (training renders batches in a background thread,
``train.prefetch``).  Beside the float32 figures, bfloat16 autocast ones (``*_bf16_*``; by default only
where bf16 is native: a GPU or a CPU with AVX512-BF16/AMX; ``--bf16`` forces them) and how far bf16
moves the losses and outputs.

``profile``: self CPU milliseconds by operator (``torch.profiler``) of one training step with D and
one inference batch per model, the largest operators first.

``time_to_accuracy``: minutes of training wall time until the network's normals beat the
dataset-mean normal map and the pseudo ground truth (mean angular error on the same pixels), read from a run's
``metrics.jsonl`` (the periodic ``val`` records and the final ``eval``; the newest run under
``outputs/`` or ``--run DIR``).
"""

from __future__ import annotations

import contextlib
import json
import statistics
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torch.utils.flop_counter import FlopCounterMode

from disent.bench import device_sync, matmul, print_table, timed_rounds
from disent.optim import autocast

CONF = Path(__file__).resolve().parents[2] / "conf"
MODELS = ("explicit", "implicit", "baseline")


# model settings every benchmarked model takes instead of conf/model's (--norm, --no-kernels)
LAYER_OVERRIDES: dict = {}


def model_cfg(name: str, resolution: int) -> dict:
    cfg = OmegaConf.to_container(OmegaConf.load(CONF / "model" / f"{name}.yaml"))
    cfg["resolution"] = resolution
    return {**cfg, **LAYER_OVERRIDES}


# A margin above every energy (D's per-value squared error of images in [0,1] is at most 1): each
# generated image is inside it, so a step runs D's whole backward pass over the generated batch too.
FULL_WORK_MARGIN = 2.0


def loss_cfg(adv: bool, margin: float | None = None):
    cfg = OmegaConf.load(CONF / "loss" / "default.yaml")
    if not adv:
        cfg.weights.adv = 0.0
    if margin is not None:
        cfg.margin = margin
    return cfg


def count_flops(fn) -> int:
    with FlopCounterMode(display=False) as counter:
        fn()
    return counter.get_total_flops()


class Trainer:
    """One model (+ optional discriminator) with its optimisers, stepping on a fixed batch.  By default
    with the EBGAN margin at ``FULL_WORK_MARGIN``, so that every step does the same, whole work."""

    def __init__(self, name, batch, adv, device, channels_last=True, amp=False, margin=FULL_WORK_MARGIN):
        from disent.models import build_model
        from disent.train import build_discriminator, make_optimizer

        fmt = torch.channels_last if channels_last else torch.contiguous_format
        res = batch["image"].shape[-1]
        torch.manual_seed(0)
        self.model = build_model(model_cfg(name, res)).to(device, memory_format=fmt)
        self.disc = build_discriminator(self.model).to(device, memory_format=fmt) if adv else None
        cfg_train = OmegaConf.load(CONF / "train" / "default.yaml")  # the training run's optimiser (conf/train)
        self.opt_g = make_optimizer(self.model, cfg_train)
        self.opt_d = make_optimizer(self.disc, cfg_train) if adv else None
        self.cfg = loss_cfg(adv, margin)
        self.batch, self.amp, self.device = batch, amp, torch.device(device)

    def compile(self) -> None:
        """torch.compile the model and D in place, as ``train.compile`` does (the next step compiles them)."""
        from disent.runtime import compile_networks

        compile_networks(self.model, self.disc)

    def step(self):
        from disent.train import train_step

        with autocast(self.device, self.amp):
            losses = train_step(self.model, self.disc, self.opt_g, self.opt_d, self.batch, self.cfg)
        if "nonfinite" in losses:
            raise FloatingPointError(f"benchmark step gave non-finite {losses['nonfinite']}")


def synth_batch(n: int, resolution: int, device, channels_last: bool, start: int = 0) -> dict:
    from disent.data import SynthFaces, get_batch, to_device
    from disent.train import TRAIN_KEYS

    ds = SynthFaces("train", resolution=resolution, seed=0)
    return to_device(get_batch(ds, range(start, start + n), TRAIN_KEYS), device, channels_last)


def loader_img_s(n: int, resolution: int, rounds: int) -> tuple[float, float]:
    """``SynthFaces.get_batch`` alone on fresh indices of ``n`` images, as training's prefetch
    thread runs it (one torch thread): (images per wall second, images per CPU second of
    this process; the second is the one a loaded machine leaves nearly unchanged)."""
    from disent.bench.data import generation_rates
    from disent.data import SynthFaces

    return generation_rates(SynthFaces("train", resolution=resolution, seed=0), n, rounds)


def cpu_has_bf16() -> bool:
    """Native bfloat16 arithmetic on this CPU (AVX512-BF16 or AMX); without it bf16 is emulated."""
    try:
        flags = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    return "avx512_bf16" in flags or "amx_bf16" in flags


def inference(model, x, device, amp: bool, sync, calls: int = 1):
    """A callable that runs ``model(x)`` ``calls`` times without autograd (bfloat16 autocast if ``amp``),
    synchronised."""

    def run():
        with torch.inference_mode(), autocast(device, amp):
            for _ in range(calls):
                model(x)
        sync()

    return run


def beside_peak(args, device, fn, items: int, rounds: int, warmup: int = 1) -> tuple[float, float]:
    """``(items/s of fn, matmul peak GFLOP/s)``, timed alternately round by round (``fn``, then one
    ``--peak-n`` matmul), each the median over ``rounds``: on a shared machine a rate and its
    peak then see the load of the same moments."""
    t_fn, t_mm = timed_rounds([fn, matmul(args.peak_n, device)], rounds, warmup)
    return items / statistics.median(t_fn), 2 * args.peak_n**3 / statistics.median(t_mm) / 1e9


def bench_one(name: str, args, device: str, sync) -> dict:
    """FLOPs per image and images/s of one model: training with and without D, inference."""
    res, rounds, channels_last, n = args.size, args.rounds, not args.no_channels_last, args.train_batch
    batch = synth_batch(n, res, device, channels_last)
    out = {}
    for key, adv, margin in (
        ("train", True, FULL_WORK_MARGIN),
        ("train_no_d", False, None),
        ("train_past_margin", True, 0.0),
    ):  # every generated image past D's margin
        tr = Trainer(name, batch, adv, device, channels_last, args.amp, margin)
        out[f"{key}_flops_per_image"] = count_flops(tr.step) / n
        if getattr(args, "compile", False):  # counted eager; timed compiled (train.compile)
            tr.compile()
        tr.step()  # warm-up (allocator, RMSprop state; the compilation with --compile)
        out[f"{key}_img_s"], out[f"{key}_peak_gflops"] = beside_peak(
            args, device, lambda: (tr.step(), sync()), n, rounds
        )
    model = tr.model.eval()
    fmt = torch.channels_last if channels_last else torch.contiguous_format
    with torch.inference_mode():
        out["flops_per_image"] = count_flops(lambda: model(batch["image"][:2])) / 2
        for B in args.infer_batches:
            x = batch["image"].repeat(-(-B // n), 1, 1, 1)[:B].contiguous(memory_format=fmt)
            calls = max(1, 64 // B)  # a small batch runs several times a round, as long as a batch of 64
            key = "infer" if B == 64 else f"infer_b{B}"
            out[f"{key}_img_s"], out[f"{key}_peak_gflops"] = beside_peak(
                args, device, inference(model, x, device, args.amp, sync, calls), B * calls, rounds, warmup=2
            )
    bf16 = getattr(args, "bf16", False)
    if bf16 is None:  # default: where bf16 is native
        bf16 = device.startswith("cuda") or cpu_has_bf16()
    if bf16 and not args.amp:
        out.update(bench_bf16(name, args, device, sync, batch))
    return out


def bench_bf16(name: str, args, device: str, sync, batch: dict) -> dict:
    """bfloat16 autocast beside float32 (the shading layer stays float32): training with D and
    inference at batch 64 in images/s, and how far bf16 moves the numbers from the same weights:
    the first step's losses (near-zero terms such as smooth_A at initialisation differ by a large
    relative amount but a tiny absolute one) and the inference outputs (max/mean absolute difference of ``recon``
    in [0,1] units, mean angle between the normals in degrees)."""
    from disent.eval.metrics import angular_error_deg
    from disent.train import train_step

    n, rounds, channels_last = args.train_batch, args.rounds, not args.no_channels_last
    out = {}
    losses = {}
    for amp in (False, True):  # same initial weights (Trainer seeds), one step each
        tr = Trainer(name, batch, True, device, channels_last, amp)
        with autocast(device, amp):
            losses[amp] = {
                k: v.item()
                for k, v in train_step(tr.model, tr.disc, tr.opt_g, tr.opt_d, tr.batch, tr.cfg).items()
                if torch.is_tensor(v)
            }
    diff = {k: abs(losses[True][k] - v) for k, v in losses[False].items()}
    out["bf16_first_step_total_rel_diff"] = diff["total"] / abs(losses[False]["total"])
    out["bf16_first_step_D_rel_diff"] = diff["D"] / abs(losses[False]["D"])
    out["bf16_first_step_term_max_abs_diff"] = max(diff.values())  # every term in its own units (~1e-3 .. 1)
    tr.step()
    out["train_bf16_img_s"], out["train_bf16_peak_gflops"] = beside_peak(
        args, device, lambda: (tr.step(), sync()), n, rounds
    )
    model = tr.model.eval()
    x = batch["image"]
    with torch.inference_mode():
        ref = model(x)
        with autocast(device, True):
            low = model(x)
        out["infer_bf16_img_s"], out["infer_bf16_peak_gflops"] = beside_peak(
            args, device, inference(model, x, device, True, sync), len(x), rounds, warmup=2
        )
    diff = (low["recon"].float() - ref["recon"]).abs()
    out["bf16_recon_max_abs_diff"], out["bf16_recon_mean_abs_diff"] = diff.max().item(), diff.mean().item()
    if "normal" in ref:
        out["bf16_normal_mean_angle_deg"] = angular_error_deg(low["normal"].float(), ref["normal"]).mean().item()
    return out


@contextlib.contextmanager
def layer_overrides(**over):
    """``LAYER_OVERRIDES`` updated by ``over`` inside the block (models built there take them)."""
    saved = dict(LAYER_OVERRIDES)
    LAYER_OVERRIDES.update(over)
    try:
        yield
    finally:
        LAYER_OVERRIDES.clear()
        LAYER_OVERRIDES.update(saved)


def interleaved_ratios(
    args,
    device: str,
    sync,
    a: str = "implicit",
    b: str = "explicit",
    layers_a: dict | None = None,
    layers_b: dict | None = None,
) -> dict:
    """Images/s of model ``a`` over model ``b`` (each built with its layer overrides), the two timed in
    alternating rounds on the same batch (training with and without D, inference at the training batch):
    on a shared machine a ratio of rates measured minutes apart carries the load of both moments,
    alternating rounds share it."""
    channels_last, n = not args.no_channels_last, args.train_batch
    batch = synth_batch(n, args.size, device, channels_last)

    def build(name, layers, adv, amp):
        with layer_overrides(**(layers or {})):
            return Trainer(name, batch, adv, device, channels_last, amp)

    out = {}
    for adv in (True, False):
        steps = [build(name, lay, adv, args.amp).step for name, lay in ((a, layers_a), (b, layers_b))]
        t_a, t_b = timed_rounds([lambda s=s: (s(), sync()) for s in steps], args.rounds)
        out["train_img_s" if adv else "train_no_d_img_s"] = statistics.median(t_b) / statistics.median(t_a)
    models = [build(name, lay, False, False).model.eval() for name, lay in ((a, layers_a), (b, layers_b))]
    t_a, t_b = timed_rounds(
        [inference(m, batch["image"], device, args.amp, sync) for m in models], args.rounds, warmup=2
    )
    out["infer_img_s"] = statistics.median(t_b) / statistics.median(t_a)
    return out


def add_fractions(fig: dict, peak_gflops: float) -> None:
    """``<key>_fraction_of_peak`` = FLOPs per image x images/s / peak FLOP/s, for every rate, against
    the peak measured beside that rate (``<key>_peak_gflops``), else ``peak_gflops``."""
    for key in [k[: -len("_img_s")] for k in fig if k.endswith("_img_s")]:
        train_key = "train" if key == "train_bf16" else key  # bf16 does the same FLOPs, stated against the fp32 peak
        flops = fig.get(f"{train_key}_flops_per_image", fig["flops_per_image"])  # inference: the forward FLOPs
        peak = fig.get(f"{key}_peak_gflops", peak_gflops)
        fig[f"{key}_fraction_of_peak"] = flops * fig[f"{key}_img_s"] / 1e9 / peak


def bench_models(args) -> dict:
    device = args.device
    sync = device_sync(device)
    figures = {name: bench_one(name, args, device, sync) for name in args.models or MODELS}
    peaks = [v for fig in figures.values() for k, v in fig.items() if k.endswith("_peak_gflops")]
    peak = statistics.median(peaks)
    for fig in figures.values():
        add_fractions(fig, peak)
    setup = {
        "peak_gflops_min_max": [min(peaks), max(peaks)],
        "threads": torch.get_num_threads(),
        "device": device,
        "train_batch": args.train_batch,
        "resolution": args.size,
        "amp": args.amp,
        "compile": getattr(args, "compile", False),
        "channels_last": not args.no_channels_last,
        "kernels": LAYER_OVERRIDES.get("kernels", True),
        "norm": LAYER_OVERRIDES.get("norm", "conf/model"),
        "malloc_tuned": getattr(args, "malloc_tuned", False),
        "bf16_avx512_bf16_or_amx": cpu_has_bf16() if not device.startswith("cuda") else None,
    }
    if "explicit" in figures and "implicit" in figures:
        setup["implicit_vs_explicit"] = interleaved_ratios(args, device, sync)
    if not device.startswith("cuda"):
        setup["loader_img_s"], setup["loader_img_cpu_s"] = loader_img_s(args.train_batch, args.size, args.rounds)
        setup["loader_vs_fastest_training"] = setup["loader_img_s"] / max(
            f["train_no_d_img_s"] for f in figures.values()
        )
        if "explicit" in figures:  # the default run's model
            setup["loader_vs_explicit_training"] = setup["loader_img_s"] / figures["explicit"]["train_img_s"]
    for name, fig in figures.items():
        print_table(f"{name}: {setup['threads']} threads, peak {peak:.1f} GFLOP/s, train batch {args.train_batch}", fig)
    print_table("setup", setup)
    return {**figures, "top": {"peak_gflops": peak, "models_setup": setup}}


def bench_norm_cost(args) -> dict:
    """What the normalisation layers cost: images/s of the explicit model (the default run's) with
    each ``model.norm`` over the same model without normalisation, timed in alternating rounds
    (training with and without D, inference at batch ``--train-batch``; BatchNorm is folded into the
    convolutions at inference, see :func:`disent.models.kernels.conv_then_norm`)."""
    device = args.device
    sync = device_sync(device)
    out = {
        norm: interleaved_ratios(args, device, sync, "explicit", "explicit", {"norm": norm}, {"norm": "none"})
        for norm in ("batch", "group")
    }
    rows = {f"{norm} {rate}": ratio for norm, ratios in out.items() for rate, ratio in ratios.items()}
    print_table("explicit images/s with each normalisation over none (alternating rounds)", rows)
    return out


# ----------------------------------------------------------------------------- profile
def top_ops(fn, calls: int = 3, top: int = 12) -> dict:
    """Self CPU milliseconds per call of ``fn`` by operator (``torch.profiler``): the ``top`` largest,
    keyed by rank and name (``"01 aten::convolution_backward"``, so that sorted keys keep the order),
    the rest summed as ``other``, and ``total``; ``convolution_share`` is the convolutions' part."""
    from torch.profiler import ProfilerActivity, profile

    fn()  # warm-up outside the profile
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(calls):
            fn()
    ms = {e.key: e.self_cpu_time_total / 1e3 / calls for e in prof.key_averages()}
    ranked = sorted(ms.items(), key=lambda kv: -kv[1])
    total = sum(ms.values())
    conv = sum(v for k, v in ms.items() if "convolution" in k)
    return {
        **{f"{i:02d} {k}": v for i, (k, v) in enumerate(ranked[:top], 1)},
        "other": sum(v for _, v in ranked[top:]),
        "total": total,
        "convolution_share": conv / total,
    }


def bench_profile(args) -> dict:
    """Where a training step with D and an inference batch spend their time, by operator."""
    channels_last, n = not args.no_channels_last, args.train_batch
    batch = synth_batch(n, args.size, args.device, channels_last)
    out = {}
    for name in args.models or MODELS:
        tr = Trainer(name, batch, True, args.device, channels_last, args.amp)
        out[f"{name}_train_step_ms"] = top_ops(tr.step)  # (top_ops warms up: allocator, RMSprop state)
        out[f"{name}_infer_batch_ms"] = top_ops(
            inference(tr.model.eval(), batch["image"], args.device, args.amp, lambda: None)
        )
        for key in (f"{name}_train_step_ms", f"{name}_infer_batch_ms"):
            print_table(
                f"{key.replace('_', ' ')} (self CPU ms per call, batch {n}, {torch.get_num_threads()} threads)",
                out[key],
            )
    return out


# ----------------------------------------------------------------------------- time to accuracy
def latest_run(root: Path = Path("outputs")) -> Path | None:
    runs = sorted(root.glob("*/*/metrics.jsonl"), key=lambda p: p.stat().st_mtime)
    return runs[-1].parent if runs else None


def accuracy_records(metrics_path: Path) -> list[dict]:
    """``(step, wall, source, metrics)`` of every record with normal errors: the periodic
    validations (``val``, see ``train.val_every``) and the final test evaluation (``eval``)."""
    out = []
    for line in Path(metrics_path).read_text().splitlines():
        rec = json.loads(line) if line.strip() else {}
        for source in ("val", "eval"):
            m = rec.get(source)
            if isinstance(m, dict) and m.get("normal_mean") is not None and m.get("pseudo_normal_mean") is not None:
                out.append({"step": rec["step"], "wall": rec["wall"], "source": source, **m})
    return out


TARGETS = (("trivial", "trivial_normal_mean"), ("pseudo_gt", "pseudo_normal_mean"))  # what the normals must beat


def time_to_accuracy(metrics_path: Path) -> dict:
    """Training wall minutes until the network's mean normal angular error first beats the dataset-mean
    normal map (``trivial``) and the pseudo-GT (``pseudo_gt``), each on the same pixels, read from a run's
    ``metrics.jsonl``.  Each target gets ``minutes``, ``step`` and ``images`` (null if never reached);
    beside them the best error reached and when."""
    recs = accuracy_records(metrics_path)
    run = str(Path(metrics_path).parent)
    if not recs:
        return {"run": run, "reason": "no validation or evaluation with normals logged"}
    batch = _run_batch_size(Path(metrics_path).parent)
    out = {"run": run}
    for name, key in TARGETS:
        hit = next((r for r in recs if r.get(key) is not None and r["normal_mean"] < r[key]), None)
        out[name] = (
            {
                "minutes": hit["wall"] / 60,
                "step": hit["step"],
                "images": hit["step"] * batch if batch else None,
                "source": hit["source"],
                "normal_mean": hit["normal_mean"],
                "target": hit[key],
            }
            if hit
            else {"minutes": None, "target": recs[-1].get(key)}
        )
    best = min(recs, key=lambda r: r["normal_mean"])
    out.update(
        {
            "best_normal_mean": best["normal_mean"],
            "best_step": best["step"],
            "best_minutes": best["wall"] / 60,
            "best_source": best["source"],
            "last_minutes": recs[-1]["wall"] / 60,
            "n_records": len(recs),
        }
    )
    return out


def _run_batch_size(run_dir: Path):
    cfg = Path(run_dir) / ".hydra" / "config.yaml"
    return OmegaConf.load(cfg).train.batch_size if cfg.exists() else None


def bench_time_to_accuracy(args) -> dict:
    run = Path(args.run) if args.run else latest_run()
    if run is None:
        out = {"minutes": None, "reason": "no run with metrics.jsonl under outputs/ (train one: python -m disent)"}
    else:
        out = time_to_accuracy(run / "metrics.jsonl" if run.is_dir() else run)
    print_table("time to accuracy (network normals beat the dataset-mean map, then the pseudo-GT)", out)
    return out
