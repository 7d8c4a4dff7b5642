"""PCT throughput in blocks/s at N = 8192 points per block: training steps and inference.

Run: python benchmarks/bench_learn.py [--full-cpu] [--steps K] [--baseline-src OLD/src]

Rows, measured side by side in one run:

- CPU, tiny model (configs/training/tiny_cpu.toml's network): one training step (forward,
  masked loss, backward, Adam, BatchNorm commit, EMA) at batch 2, and inference passes
  (forward + softmax + vote accumulation, the code path of evaluate/predict) at batch 2.
- CPU, full model (Table 2, 2.4M parameters) with --full-cpu: about 25 s per training step on
  2 cores (PERFORMANCE.md), so off by default.
- CUDA, full model, when a GPU is visible: AMP float16 with GradScaler as in training, and
  bfloat16; the same functions the training loop and the block runner call.
- CPU, the CPU recipe's network and inputs (configs/experiments/sim2real_cpu.toml: 55k parameters, 10 input
  channels) at its batch, 4 blocks of 1024 points: one training step with no block padded and
  with every block padded as the recipe's point dropout pads them (each block loses a random
  share up to AugmentConfig's dropout_max; padded points are masked), and their ratio. With ``--baseline-src`` the same two rows for the network module
  (``bimscan/learn/model.py``) of another checkout, interleaved, and the ratios between them.
- Block sampling (TileDataset, data side) in blocks/s of one loader process, XYZ only and with the
  recipe's augmentations and features: what a GPU waits for unless enough workers feed it.

Throughput is the best of the timed repetitions after one warm-up (first calls allocate and
pick kernels). Peak memory: CUDA max allocated, or the process's peak RSS on CPU.
"""

from __future__ import annotations

import argparse
import importlib.util
import resource
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import torch

from bimscan.learn import model as model_module
from bimscan.learn.blocks import pad_block
from bimscan.learn.features import input_channels
from bimscan.learn.train_config import AugmentConfig, InputConfig, ModelConfig, TrainConfig, load_train_config
from bimscan.learn.data import TileDataset, TileSet
from bimscan.learn.infer import BlockRunner
from bimscan.learn.model import build_model, count_parameters
from bimscan.learn.train import WeightEMA, finish_step, run_micro_batch
from bimscan.toml_files import build_dataclass, load_toml

N = 8192
BATCH = 2
FULL = ModelConfig()
CONFIGS = Path(__file__).resolve().parents[1] / "configs"
RECIPE_POINTS = 1024


def tiny_model_config() -> ModelConfig:
    config, _ = load_train_config(CONFIGS / "training" / "tiny_cpu.toml")
    return config.model


def synthetic_blocks(count: int, seed: int = 0) -> list[dict[str, np.ndarray]]:
    """Room-like blocks: points on a floor, a ceiling and two walls, labelled by surface."""
    rng = np.random.default_rng(seed)
    blocks = []
    for _ in range(count):
        surface = rng.integers(0, 4, N)
        xyz = rng.random((N, 3)) * [4.0, 4.0, 3.0]
        xyz[surface == 0, 2] = 0.0
        xyz[surface == 1, 2] = 3.0
        xyz[surface == 2, 0] = 0.0
        xyz[surface == 3, 1] = 4.0
        block = pad_block(xyz, surface.astype(np.uint8), np.arange(N), points=N)
        blocks.append({"xyz": block.xyz, "label": block.label, "mask": block.mask})
    return blocks


def stack(items: list[dict[str, np.ndarray]], device: torch.device) -> tuple[torch.Tensor, ...]:
    return tuple(torch.from_numpy(np.stack([it[k] for it in items])).to(device) for k in ("xyz", "label", "mask"))


def timed(fn: Callable[[], None], *, repeats: int, device: torch.device) -> float:
    fn()  # warm-up
    best = float("inf")
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - start)
    return best


def measure(name: str, config: ModelConfig, device: torch.device, amp: str, repeats: int) -> dict[str, object]:
    torch.manual_seed(0)
    model = build_model(5, config).to(device)
    ema = WeightEMA(model, alpha=0.99)
    optimizer = torch.optim.Adam(model.parameters(), lr=2e-3, weight_decay=5e-4)
    scaler = torch.amp.GradScaler(device.type, enabled=device.type == "cuda" and amp == "float16")
    xyz, label, mask = stack(synthetic_blocks(BATCH), device)
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)

    def train_step() -> None:
        model.train()
        run_micro_batch(model, xyz, label, mask, scaler=scaler, amp=amp, accumulation=1)
        finish_step(model, optimizer=optimizer, scaler=scaler, scheduler=None, ema=ema)

    runner = BlockRunner(ema.module.eval(), device=device, batch_size=BATCH, amp=amp)
    blocks = [pad_block(np.asarray(b["xyz"], np.float64), None, np.arange(N), points=N)
              for b in synthetic_blocks(BATCH, seed=1)]

    def infer_pass() -> None:
        runner.votes = np.zeros((N, 5), dtype=np.float32)
        for block in blocks:
            runner.add(block)
        runner.flush()

    # run_micro_batch, finish_step and the runner flush denormals themselves, as in training
    train_s = timed(train_step, repeats=repeats, device=device)
    infer_s = timed(infer_pass, repeats=repeats, device=device)
    peak = (torch.cuda.max_memory_allocated(device) / 2**30 if device.type == "cuda"
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20)
    return {
        "row": name, "device": device.type, "params": count_parameters(model), "amp": amp if device.type == "cuda" else "fp32",
        "train_s": train_s, "train_bps": BATCH / train_s, "infer_bps": BATCH / infer_s, "peak_gib": peak,
    }


def recipe_network() -> tuple[ModelConfig, int, int]:
    """The CPU recipe's model config, input channels and batch size, read from its experiment file
    by the config parser the experiment uses (its shared sections; no data paths are checked)."""
    path = CONFIGS / "experiments" / "sim2real_cpu.toml"
    data = load_toml(path)
    model = build_dataclass(ModelConfig, data["model"], where=f"{path} [model]")
    inputs = build_dataclass(InputConfig, data["input"], where=f"{path} [input]")
    train = build_dataclass(TrainConfig, data["train"], where=f"{path} [train]")
    return model, input_channels(inputs.features), train.batch_size


def load_model_module(src: Path) -> ModuleType:
    """``bimscan/learn/model.py`` of another checkout, as a module of its own (the rest of bimscan is this one's)."""
    path = src / "bimscan" / "learn" / "model.py"
    if not path.is_file():
        raise SystemExit(f"--baseline-src {src}: no bimscan/learn/model.py there; give the src folder of a checkout")
    spec = importlib.util.spec_from_file_location("baseline_model", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def recipe_steps(modules: dict[str, ModuleType], repeats: int) -> dict[tuple[str, str], float]:
    """Best seconds per training step of the recipe's network, per (checkout, batch), interleaved."""
    config, channels, batch = recipe_network()
    rng = np.random.default_rng(0)
    xyz = torch.from_numpy(rng.standard_normal((batch, RECIPE_POINTS, channels)).astype(np.float32))
    label = torch.from_numpy(rng.integers(0, 5, (batch, RECIPE_POINTS)))
    dropped = rng.uniform(0.0, AugmentConfig().dropout_max, batch)  # as augment_points draws it per block
    padded = torch.from_numpy(np.arange(RECIPE_POINTS)[None, :] < np.round(RECIPE_POINTS * (1.0 - dropped))[:, None])
    masks = {"no block padded": torch.ones(batch, RECIPE_POINTS, dtype=torch.bool), "every block padded": padded}
    best: dict[tuple[str, str], float] = {}
    for _ in range(repeats):
        for checkout, module in modules.items():
            for kind, mask in masks.items():
                torch.manual_seed(0)
                model = module.build_model(5, config, in_dim=channels)
                optimizer = torch.optim.Adam(model.parameters(), lr=5e-3)
                scaler = torch.amp.GradScaler("cpu", enabled=False)  # a no-op on the CPU, as in training
                target = label.masked_fill(~mask, 255)

                def step() -> None:  # run_micro_batch and finish_step, with the checkout's own BatchNorm commit
                    model.train()
                    run_micro_batch(model, xyz, target, mask, scaler=scaler, amp="off", accumulation=1)
                    with module.flush_denormals():
                        optimizer.step()
                        optimizer.zero_grad(set_to_none=True)
                        module.commit_batch_statistics(model)

                step()  # warm-up
                start = time.perf_counter()
                for _ in range(5):
                    step()
                seconds = (time.perf_counter() - start) / 5
                best[(checkout, kind)] = min(best.get((checkout, kind), float("inf")), seconds)
    return best


def sampling_rate(repeats: int = 200, *, recipe: bool = False) -> float:
    """Blocks/s of one loader process: the paper's block (XYZ), or the recipe's (augmentations,
    then height, normals and shape from the block's points: what the GPU run waits for)."""
    rng = np.random.default_rng(0)
    points = 16384
    tiles = TileSet(
        xyz=(rng.random((points * 8, 3)) * 4).astype(np.float32), label=rng.integers(0, 5, points * 8).astype(np.uint8),
        offsets=np.arange(9, dtype=np.int64) * points, origin=np.zeros((8, 3)), key=np.arange(8, dtype=np.int64),
        count=np.full(8, points, dtype=np.int64), scene=np.zeros(8, dtype=np.int32), scene_names=("bench",),
        height=(rng.random(points * 8) * 3).astype(np.float32),
    )
    dataset = (TileDataset(tiles, points=N, seed=0, inputs=InputConfig(), augment=AugmentConfig()) if recipe
               else TileDataset(tiles, points=N, seed=0))
    start = time.perf_counter()
    for i in range(repeats):
        dataset[(i, i % 8)]
    return repeats / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--full-cpu", action="store_true", help="also time the full model on the CPU (slow)")
    parser.add_argument("--steps", type=int, default=3, help="timed repetitions per row (after a warm-up)")
    parser.add_argument("--baseline-src", type=Path,
                        help="the src folder of an earlier checkout: its network module's recipe steps beside these")
    args = parser.parse_args()
    modules = {"this checkout": model_module}
    if args.baseline_src:  # before any timing: a wrong path fails at once
        modules["baseline"] = load_model_module(args.baseline_src.resolve())
    print(f"torch {torch.__version__}, {torch.get_num_threads()} CPU threads, N = {N}, batch {BATCH}", file=sys.stderr)
    rows = [measure("tiny", tiny_model_config(), torch.device("cpu"), "off", args.steps)]
    if args.full_cpu:
        rows.append(measure("full (Table 2)", FULL, torch.device("cpu"), "off", max(1, args.steps // 3)))
    if torch.cuda.is_available():
        cuda = torch.device("cuda")
        rows.append(measure("full (Table 2)", FULL, cuda, "float16", args.steps))
        rows.append(measure("full (Table 2)", FULL, cuda, "bfloat16", args.steps))
    else:
        print("no CUDA device: the GPU rows (full model, AMP) are skipped", file=sys.stderr)
    print(f"\n{'model':<16}{'device':<8}{'params':>10}{'precision':>11}{'s/step':>9}{'train blk/s':>13}"
          f"{'infer blk/s':>13}{'peak GiB':>10}")
    for r in rows:
        print(f"{r['row']:<16}{r['device']:<8}{r['params']:>10,}{r['amp']:>11}{r['train_s']:>9.2f}"
              f"{r['train_bps']:>13.2f}{r['infer_bps']:>13.2f}{r['peak_gib']:>10.2f}")
    if len(rows) > 1:
        base = rows[0]
        for r in rows[1:]:
            print(f"{r['row']} on {r['device']} ({r['amp']}) / tiny on cpu: training {r['train_bps'] / base['train_bps']:.1f}x, "
                  f"inference {r['infer_bps'] / base['infer_bps']:.1f}x")
    steps = recipe_steps(modules, max(3, args.steps))
    config, channels, batch = recipe_network()
    print(f"\nthe CPU recipe's training step (batch {batch} x {RECIPE_POINTS} points, {channels} input channels, "
          f"embed {config.embed_dim}), best of {max(3, args.steps)} interleaved rounds of 5 steps:")
    for checkout in modules:
        full, padded = steps[(checkout, "no block padded")], steps[(checkout, "every block padded")]
        print(f"  {checkout:<14} no block padded {full:.3f} s, every block padded {padded:.3f} s: "
              f"padded / unpadded {padded / full:.2f}")
    if "baseline" in modules:
        for kind in ("no block padded", "every block padded"):
            print(f"  {kind}: baseline / this checkout {steps[('baseline', kind)] / steps[('this checkout', kind)]:.2f}x")
    print(f"\nblock sampling, one loader process (TileDataset, 8192 of 16384 cached points): "
          f"{sampling_rate():.0f} blocks/s XYZ only, {sampling_rate(20, recipe=True):.1f} blocks/s with the recipe's "
          f"augmentations and features (each DataLoader worker adds one such process)")


if __name__ == "__main__":
    main()
