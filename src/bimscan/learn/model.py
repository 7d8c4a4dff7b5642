"""PCT for semantic segmentation (Guo et al. 2021, "PCT: Point Cloud Transformer"), in plain PyTorch.

Layout of the segmentation network, point features on channels (B, D, N):

1. Point embedding: two 1x1 convolutions 3 -> d -> d (no bias) with BatchNorm and ReLU.
2. ``attention_layers`` offset-attention layers of width d (d = 128 in the paper): q and k share
   one projection to d/4; energy = q^T k; softmax over keys (last dim) then L1 re-normalisation
   over queries; the offset (x - attended) goes through a 1x1 conv + BN + ReLU and is added back.
3. The layer outputs concatenated (4 x 128 = 512) and fused by a 1x1 conv to 1024 + BN + LeakyReLU.
4. Global max and mean of the fused features, broadcast back to every point: 3 x 1024 = 3072.
5. Head 3072 -> 512 -> 256 -> C: conv + BN + ReLU (+ dropout after the first), then logits.

Padding: blocks with fewer than N points are zero-padded and come with a validity mask (B, N).
Padded points are masked out of the attention (as keys, and as contributors to every output),
out of the global pooling and out of the batch statistics of every BatchNorm
(:class:`MaskedBatchNorm1d`), so the outputs at valid points do not depend on the padding,
in training as in evaluation. Their own outputs are meaningless and must be ignored.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import torch
import torch.distributed as dist
from torch import nn

from bimscan.errors import LearnError
from bimscan.learn.train_config import ModelConfig

# what to do when a checkpoint's outputs overflow (non_finite_outputs)
CHECKPOINT_ADVICE = "pass another checkpoint, or train again with a lower [train] max_lr"
# The largest output the network may give: float16's largest number. A network trained under
# float16 AMP (Table 2) cannot give more, and a trained network's outputs are far smaller (a gap of
# 104 between two already makes a float32 softmax exactly one-hot); past it they are overflow.
MAX_OUTPUT = 65504.0


class MaskedBatchNorm1d(nn.Module):
    """BatchNorm over (B, C, N) whose training statistics use the valid points only.

    Normalisation in training uses the statistics of the current (micro-)batch, as usual.
    The running statistics are not updated per forward: the layer accumulates the sums of
    every training forward and :meth:`commit_statistics` folds them in once per optimizer
    step (summed over processes under DDP), so the running statistics do not depend on how a
    global batch was split into micro-batches and processes. Neither step waits for the GPU
    (no value goes to the host).
    """

    def __init__(self, channels: int, *, momentum: float = 0.1, eps: float = 1e-5) -> None:
        super().__init__()
        self.channels = channels
        self.momentum = momentum
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(channels))
        self.bias = nn.Parameter(torch.zeros(channels))
        self.register_buffer("running_mean", torch.zeros(channels))
        self.register_buffer("running_var", torch.ones(channels))
        # float64 sums of the valid points since the last commit: count, sum, sum of squares
        self.register_buffer("pending", torch.zeros(2 * channels + 1, dtype=torch.float64), persistent=False)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """x (B, C, N) float, mask (B, N) bool or None (all valid) -> (B, C, N) in x's dtype."""
        dtype = x.dtype
        x = x.float()
        if self.training:
            count: torch.Tensor | float
            if mask is None:
                var, mean = torch.var_mean(x, dim=(0, 2), correction=0)
                count = float(x.shape[0] * x.shape[2])  # a Python number: no host-to-device copy
            else:
                # masked_fill, not a product with the mask: padded values may be anything
                padded = ~mask.unsqueeze(1)  # (B, 1, N)
                count = mask.sum().to(x.dtype).clamp_min(1.0)
                mean = x.masked_fill(padded, 0.0).sum(dim=(0, 2)) / count
                centred = (x - mean[None, :, None]).masked_fill(padded, 0.0)
                var = (centred * centred).sum(dim=(0, 2)) / count
            with torch.no_grad():  # sums for the running statistics, from this batch's moments
                n = count.double() if isinstance(count, torch.Tensor) else count
                mean_d = mean.detach().double()
                self.pending[0] += n
                self.pending[1:1 + self.channels] += mean_d * n
                self.pending[1 + self.channels:] += (var.detach().double() + mean_d * mean_d) * n
        else:
            mean, var = self.running_mean, self.running_var
        out = (x - mean[None, :, None]) * torch.rsqrt(var[None, :, None] + self.eps)
        out = out * self.weight[None, :, None] + self.bias[None, :, None]
        return out.to(dtype)

    @torch.no_grad()
    def commit_statistics(self, group: dist.ProcessGroup | None = None) -> None:
        """Fold the accumulated sums into the running statistics (all-reduced under DDP)."""
        if dist.is_available() and dist.is_initialized():
            dist.all_reduce(self.pending, group=group)
        self.fold_pending()

    @torch.no_grad()
    def fold_pending(self) -> None:
        """Fold this process's pending sums (already all-reduced) into the running statistics.

        Tensor operations only (a step with fewer than 2 points leaves them unchanged), so the
        GPU is never waited for.
        """
        count = self.pending[0]
        mean = self.pending[1:1 + self.channels] / count
        var = (self.pending[1 + self.channels:] / count - mean * mean).clamp_min(0.0)
        var = var * count / (count - 1.0)  # unbiased, as nn.BatchNorm's running_var
        update = count >= 2
        new_mean = self.running_mean * (1.0 - self.momentum) + self.momentum * mean.float()
        new_var = self.running_var * (1.0 - self.momentum) + self.momentum * var.float()
        self.running_mean.copy_(torch.where(update, new_mean, self.running_mean))
        self.running_var.copy_(torch.where(update, new_var, self.running_var))
        self.pending.zero_()


class ConvBlock(nn.Module):
    """1x1 conv + masked BN + activation on (B, C_in, N) -> (B, C_out, N)."""

    def __init__(self, c_in: int, c_out: int, *, activation: nn.Module, bias: bool = False) -> None:
        super().__init__()
        self.conv = nn.Conv1d(c_in, c_out, 1, bias=bias)
        self.norm = MaskedBatchNorm1d(c_out)
        self.act = activation

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        return self.act(self.norm(self.conv(x), mask))


ATTENTION_CACHE_FLOATS = 1 << 19  # 2 MiB of float32 attention per slice: in a core's L2/L3 share


class OffsetAttention(nn.Module):
    """PCT's offset-attention layer on (B, D, N) features with a (B, N) validity mask.

    A = softmax_rows(q^T k) with q = k = W x (shared, D/4 channels); each column of A is then
    divided by its sum over the queries (L1) and the layer adds LBR(x - x_v A) to x. The
    column division is applied to x_v A instead of to A (the same numbers: it scales columns),
    which saves two N x N tensors per layer; at N = 8192 one is 256 MiB per block in float32.
    Padded points are masked out as keys (-inf energy) and as queries (zero values, and left
    out of the column sums). Everything from the energy to the normalised attended values runs
    in float32 under AMP (see forward).
    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.qk = nn.Conv1d(channels, channels // 4, 1, bias=False)  # shared query/key projection
        self.v = nn.Conv1d(channels, channels, 1)
        self.trans = nn.Conv1d(channels, channels, 1)
        self.norm = MaskedBatchNorm1d(channels)
        self.act = nn.ReLU()

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        if not torch.is_grad_enabled():
            return self._forward_rows(x, mask)
        q = self.qk(x)  # (B, D/4, N)
        values = self.v(x)
        # energy, softmax and column sums in float32 even under AMP: float16 energies overflow
        # (max 65504) and 1e-9 + 0 is 0 in float16, so padded columns would divide 0 by 0; the
        # attended values too: the columns of the softmax are not yet L1-normalised, so a column
        # sum (up to N = 8192 queries) times large values would overflow float16 before the division
        with torch.autocast(device_type=x.device.type, enabled=False):
            qf = q.float()
            carried, key_bias = _carried_and_key_bias(values, mask)
            rows = qf.transpose(1, 2)
            # the key mask rides in the product (no pass of its own over the N x N energy, nor
            # over its gradient): the two passes made a padded recipe step 1.24-1.35x as long
            energy = torch.bmm(rows, qf) if key_bias is None else torch.baddbmm(key_bias, rows, qf)
            attention = torch.softmax(energy, dim=-1)  # (B, N_query, N_key)
            del energy  # not needed by backward: free it before the next N x N tensor
            total = torch.bmm(carried, attention)  # (B, D + 1, N): j sums over i, the column sums last
            attended = total[:, :-1] / (1e-9 + total[:, -1:])
        return self._offset(x, attended, mask)

    def _offset(self, x: torch.Tensor, attended: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """The layer's output from its input and the normalised attended values: x + LBR(x - x_v A)."""
        return x + self.act(self.norm(self.trans(x - attended.to(x.dtype)), mask))

    def _forward_rows(self, x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """The same layer without gradients, ``ATTENTION_CACHE_FLOATS`` of attention at a time.

        The whole (B, N, N) attention is memory traffic, not arithmetic, at the network's
        width (D/4 = 8 channels of energy): written by one product, read and written by the
        softmax, read by the product with the values. Here query rows are taken a slice at a
        time, small enough to stay in the processor's cache through energy, softmax and the
        product with the values. The same sums in another order: float32 rounding apart, the
        same result (3.3x faster on the CPU recipe's batches of 16 x 1024 points, 2 cores).
        Training keeps the whole attention: autograd needs it, and a sliced backward that
        computes it again measured slower on the CPU recipe's steps.
        """
        q = self.qk(x)
        values = self.v(x)
        with torch.autocast(device_type=x.device.type, enabled=False):
            qf = q.float()
            rows_first = qf.transpose(1, 2).contiguous()  # (B, N, D/4)
            carried, key_bias = _carried_and_key_bias(values, mask)
            batch, _, n = carried.shape
            step = max(1, min(n, ATTENTION_CACHE_FLOATS // max(1, batch * n)))
            total = qf.new_zeros(carried.shape)
            for start in range(0, n, step):
                rows = rows_first[:, start:start + step]
                energy = torch.bmm(rows, qf) if key_bias is None else torch.baddbmm(key_bias, rows, qf)
                total.baddbmm_(carried[:, :, start:start + step], torch.softmax(energy, dim=-1))
            attended = total[:, :-1] / (1e-9 + total[:, -1:])
        return self._offset(x, attended, mask)


def _carried_and_key_bias(values: torch.Tensor, mask: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """What the attention sums over the queries, and what it adds to the energy of each key.

    carried (B, D + 1, N) float32: the values, with one more row that counts each query, so the
    product with the attention gives the attended values and the column sums (the L1) at once.
    Padded queries send nothing and count nothing (zero columns). key_bias (B, 1, N): -inf at
    padded keys, so they get no weight (None without padding).
    """
    batch, _, n = values.shape
    if mask is None:
        return torch.cat([values.float(), values.new_ones(batch, 1, n, dtype=torch.float32)], dim=1), None
    padded = ~mask[:, None, :]
    carried = torch.cat([values.float().masked_fill(padded, 0.0), mask[:, None, :].float()], dim=1)
    return carried, values.new_zeros(batch, 1, n, dtype=torch.float32).masked_fill_(padded, float("-inf"))


class PCTSegmentation(nn.Module):
    """PCT segmentation network: (B, N, in_dim) inputs (xyz first) + (B, N) mask -> (B, N, C) logits."""

    def __init__(self, num_classes: int, config: ModelConfig | None = None, *, in_dim: int = 3) -> None:
        super().__init__()
        config = config or ModelConfig()
        d = config.embed_dim
        self.config = config
        self.num_classes = num_classes
        self.embed1 = ConvBlock(in_dim, d, activation=nn.ReLU())
        self.embed2 = ConvBlock(d, d, activation=nn.ReLU())
        self.attention = nn.ModuleList(OffsetAttention(d) for _ in range(config.attention_layers))
        self.fuse = ConvBlock(d * config.attention_layers, config.fuse_dim, activation=nn.LeakyReLU(0.2))
        head: list[ConvBlock] = []
        width = 3 * config.fuse_dim
        for out in config.head_dims:
            head.append(ConvBlock(width, out, activation=nn.ReLU()))
            width = out
        self.head = nn.ModuleList(head)
        self.dropout = nn.Dropout(config.dropout)
        self.classifier = nn.Conv1d(width, num_classes, 1)

    def forward(self, xyz: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """xyz (B, N, 3) normalised coordinates; mask (B, N) bool, True = real point.

        Returns logits (B, N, C). Without a mask every point is real.
        """
        if mask is not None and bool(mask.all()):
            mask = None  # blocks without padding take the cheaper unmasked path
        x = xyz.transpose(1, 2)
        x = self.embed2(self.embed1(x, mask), mask)
        layers = []
        for layer in self.attention:
            x = layer(x, mask)
            layers.append(x)
        fused = self.fuse(torch.cat(layers, dim=1), mask)  # (B, F, N)
        if mask is None:
            pooled_max = fused.amax(dim=2, keepdim=True)
            pooled_mean = fused.mean(dim=2, keepdim=True)
        else:
            valid = mask[:, None, :]
            pooled_max = fused.masked_fill(~valid, float("-inf")).amax(dim=2, keepdim=True)
            count = valid.sum(dim=2, keepdim=True).clamp_min(1).to(fused.dtype)
            pooled_mean = fused.masked_fill(~valid, 0.0).sum(dim=2, keepdim=True) / count
        n = fused.shape[2]
        x = torch.cat([fused, pooled_max.expand(-1, -1, n), pooled_mean.expand(-1, -1, n)], dim=1)
        for i, block in enumerate(self.head):
            x = block(x, mask)
            if i == 0:
                x = self.dropout(x)
        return self.classifier(x).transpose(1, 2)


def build_model(num_classes: int, config: ModelConfig | None = None, *, in_dim: int = 3) -> PCTSegmentation:
    """A PCT segmentation network for ``num_classes`` classes and ``in_dim`` input channels
    (3: the paper's XYZ; more with extra features, :func:`bimscan.learn.features.input_channels`)."""
    return PCTSegmentation(num_classes, config, in_dim=in_dim)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def commit_batch_statistics(model: nn.Module) -> None:
    """Fold every masked BatchNorm's pending sums into its running statistics (call per step).

    Under DDP the sums of all layers travel in one all-reduce, not one per layer.
    """
    norms = [m for m in model.modules() if isinstance(m, MaskedBatchNorm1d)]
    if not norms:
        return
    if dist.is_available() and dist.is_initialized():
        flat = torch.cat([m.pending for m in norms])
        dist.all_reduce(flat)
        for norm, part in zip(norms, flat.split([len(m.pending) for m in norms]), strict=True):
            norm.pending.copy_(part)
    for norm in norms:
        norm.fold_pending()


def pick_device(setting: str) -> torch.device:
    """The device for "auto" (CUDA when present, else CPU), "cpu" or "cuda"/"cuda:N".

    LearnError when CUDA is asked for and none is visible.
    """
    if setting == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if setting.startswith("cuda") and not torch.cuda.is_available():
        raise LearnError(f"device {setting!r} asked for but no CUDA device is visible; use device 'auto' or 'cpu'")
    return torch.device(setting)


@contextlib.contextmanager
def flush_denormals() -> Iterator[None]:
    """Flush denormal floats to zero on the CPU while the block runs, then turn it off again.

    Attention weights near zero produce denormals that slow CPU kernels about tenfold; flushing
    them changes no result measurably. The setting holds for all code of the thread (NumPy and
    SciPy too), so it is scoped to the network's forward, backward and optimizer step (the
    functions that run them use it: ``run_micro_batch``, ``finish_step``, ``BlockRunner.flush``),
    never left on and never around other numeric code: SciPy's cKDTree (the normals' and shape
    features' neighbour search) crashed the process with a segmentation fault on some blocks
    while it was on.
    """
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def autocast_context(device: torch.device, amp: str) -> contextlib.AbstractContextManager[Any]:
    """Mixed precision for ``amp`` ("float16", "bfloat16", "off") on CUDA; float32 elsewhere.

    CPU runs stay in float32: CPU autocast would run bfloat16 kernels that are slower on
    ordinary CPUs and change the numbers the CPU tests compare bit for bit.
    """
    if device.type != "cuda" or amp == "off":
        return contextlib.nullcontext()
    return torch.autocast(device_type="cuda", dtype=torch.float16 if amp == "float16" else torch.bfloat16)


def outputs_finite(logits: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """A bool tensor (on the outputs' device, no synchronisation): True when every valid point's
    (``mask`` (B, N) bool) outputs ``logits`` (B, N, C) are finite and within ``MAX_OUTPUT``
    (padding may hold anything)."""
    return ((logits.detach().abs() <= MAX_OUTPUT).all(dim=-1) | ~mask).all()  # NaN compares False


def non_finite_outputs(*, model: str, where: str, advice: str = CHECKPOINT_ADVICE) -> LearnError:
    """The error for outputs that overflow (``outputs_finite``): weights that are finite but absurd
    (a damaged checkpoint's, a diverging run's) overflow the network, and its softmax then labels
    every point alike. ``model`` names the weights (a checkpoint), ``where`` what they were
    labelling, ``advice`` what to do."""
    return LearnError(f"{model}: the network's outputs on {where} overflow (NaN, infinite or beyond "
                      f"{MAX_OUTPUT:,.0f}): its weights are finite but absurd; {advice}")


def check_finite_outputs(logits: torch.Tensor, mask: torch.Tensor, *, model: str, where: str,
                         advice: str = CHECKPOINT_ADVICE) -> None:
    """``non_finite_outputs`` raised unless ``outputs_finite``. Synchronises once (its callers copy
    the outputs to the CPU next anyway)."""
    if not bool(outputs_finite(logits, mask)):
        raise non_finite_outputs(model=model, where=where, advice=advice)
