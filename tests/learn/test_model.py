"""PCT segmentation network: shapes, paper size, masking of padded points, and a real
learning check (a tiny model overfits one block on CPU)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch

from bimscan.learn.blocks import sample_block
from bimscan.learn import model as model_module
from bimscan.learn.train_config import ModelConfig
from bimscan.learn.model import (
    MaskedBatchNorm1d, OffsetAttention, build_model, commit_batch_statistics, count_parameters,
)
from bimscan.learn.train import compute_loss
from bimscan.types import PointCloud

TINY = ModelConfig(embed_dim=16, attention_layers=2, fuse_dim=32, head_dims=(32, 16), dropout=0.0)


@pytest.mark.parametrize("points", [16, 100, 257])
def test_model_maps_points_to_class_logits_for_several_block_sizes(points: int) -> None:
    torch.manual_seed(0)
    model = build_model(5, TINY)

    logits = model(torch.randn(3, points, 3))

    assert logits.shape == (3, points, 5)
    assert torch.isfinite(logits).all()


def test_default_model_is_the_paper_size() -> None:
    model = build_model(5)

    # Guo et al.'s segmentation PCT at C = 5: about 2.4M parameters
    assert 2.3e6 < count_parameters(model) < 2.5e6
    assert len(model.attention) == 4
    assert model.attention[0].qk.out_channels == 128 // 4  # shared q/k projection to d/4


def test_offset_attention_equals_the_reference_formula() -> None:
    torch.manual_seed(3)
    layer = OffsetAttention(16).eval()
    x = torch.randn(2, 16, 50)

    # Guo et al.'s layer written out: softmax over keys, then L1 over queries, then the offset
    q = layer.qk(x)
    attention = torch.softmax(torch.bmm(q.transpose(1, 2), q), dim=-1)
    attention = attention / (1e-9 + attention.sum(dim=1, keepdim=True))
    attended = torch.bmm(layer.v(x), attention)
    expected = x + layer.act(layer.norm(layer.trans(x - attended), None))

    torch.testing.assert_close(layer(x, None), expected, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("slice_floats", [1, 2 * 64 * 7, 1 << 19])  # one query row, 7 rows, all rows at a time
@pytest.mark.parametrize("padded", [False, True])
def test_offset_attention_without_gradients_gives_the_layer_with_gradients(
    slice_floats: int, padded: bool, monkeypatch: pytest.MonkeyPatch,
) -> None:
    # inference takes the attention a slice of query rows at a time (cache-sized); training the whole
    monkeypatch.setattr(model_module, "ATTENTION_CACHE_FLOATS", slice_floats)
    torch.manual_seed(5)
    layer = OffsetAttention(16).eval()
    x = torch.randn(2, 16, 64)
    mask = None
    if padded:
        mask = torch.ones(2, 64, dtype=torch.bool)
        mask[1, 40:] = False
        x[1, :, 40:] = 7.0  # padding values must not matter

    with torch.enable_grad():
        whole = layer(x, mask)
    with torch.inference_mode():
        sliced = layer(x, mask)

    torch.testing.assert_close(sliced, whole, atol=1e-5, rtol=1e-5)
    if padded:  # the padded block's real points see what they would see alone
        with torch.inference_mode():
            alone = layer(x[1:, :, :40], None)
        torch.testing.assert_close(sliced[1:, :, :40], alone, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("mode", ["eval", "train"])
def test_padded_points_do_not_change_outputs_at_valid_points(mode: str) -> None:
    torch.manual_seed(1)
    model = build_model(5, TINY)
    getattr(model, mode)()
    xyz = torch.randn(2, 90, 3)
    padded = torch.cat([xyz, torch.zeros(2, 38, 3)], dim=1)
    padded[1, 90:] = 5.0  # padding values must not matter either
    mask = torch.zeros(2, 128, dtype=torch.bool)
    mask[:, :90] = True

    plain = model(xyz)
    masked = model(padded, mask)

    torch.testing.assert_close(masked[:, :90], plain, atol=2e-5, rtol=1e-4)


def test_padded_points_do_not_change_the_gradients() -> None:
    # training pads every recipe block (point dropout): the masked attention's backward must give
    # every weight the gradient the unpadded blocks give it, whatever the padding holds
    torch.manual_seed(2)
    plain_model = build_model(5, TINY)
    padded_model = build_model(5, TINY)
    padded_model.load_state_dict(plain_model.state_dict())
    xyz = torch.randn(2, 90, 3)
    label = torch.randint(0, 5, (2, 90))
    padded = torch.cat([xyz, torch.full((2, 38, 3), 4.0)], dim=1)
    padded_label = torch.cat([label, torch.full((2, 38), 255)], dim=1)
    mask = torch.zeros(2, 128, dtype=torch.bool)
    mask[:, :90] = True

    compute_loss(plain_model.train()(xyz), label, None)[0].backward()
    compute_loss(padded_model.train()(padded, mask), padded_label, None)[0].backward()

    for (name, plain), padded_parameter in zip(plain_model.named_parameters(), padded_model.parameters(), strict=True):
        assert torch.isfinite(padded_parameter.grad).all(), name
        torch.testing.assert_close(padded_parameter.grad, plain.grad, atol=1e-5, rtol=1e-4, msg=name)


@pytest.mark.parametrize(("dtype", "tolerance"), [(torch.float16, 5e-3), (torch.bfloat16, 5e-2)])
def test_mixed_precision_keeps_padded_blocks_finite_and_close_to_float32(dtype: torch.dtype, tolerance: float) -> None:
    # CUDA training autocasts the same way; CPU autocast runs the same code on this machine
    torch.manual_seed(4)
    model = build_model(5, TINY)
    xyz = torch.randn(2, 128, 3)
    mask = torch.ones(2, 128, dtype=torch.bool)
    mask[:, 100:] = False
    xyz[:, 100:] = 0.0
    label = torch.randint(0, 5, (2, 128))
    label[:, 100:] = 255

    model.eval()
    reference = model(xyz, mask)
    with torch.autocast("cpu", dtype=dtype):
        mixed = model(xyz, mask)
    model.train()
    with torch.autocast("cpu", dtype=dtype):
        loss, _ = compute_loss(model(xyz, mask), label)
    loss.backward()

    assert mixed.dtype == dtype and torch.isfinite(mixed).all()
    torch.testing.assert_close(mixed[:, :100].float(), reference[:, :100], atol=tolerance, rtol=tolerance)
    assert torch.isfinite(loss)
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_padded_points_stay_out_of_batch_statistics() -> None:
    torch.manual_seed(2)
    norm_plain, norm_padded = MaskedBatchNorm1d(4), MaskedBatchNorm1d(4)
    x = torch.randn(2, 4, 50)
    padded = torch.cat([x, torch.full((2, 4, 14), 100.0)], dim=2)
    mask = torch.zeros(2, 64, dtype=torch.bool)
    mask[:, :50] = True

    norm_plain(x, torch.ones(2, 50, dtype=torch.bool))
    norm_padded(padded, mask)
    norm_plain.commit_statistics()
    norm_padded.commit_statistics()

    torch.testing.assert_close(norm_padded.running_mean, norm_plain.running_mean)
    torch.testing.assert_close(norm_padded.running_var, norm_plain.running_var)
    expected_mean = 0.1 * x.permute(1, 0, 2).reshape(4, -1).mean(dim=1)
    torch.testing.assert_close(norm_plain.running_mean, expected_mean, atol=1e-6, rtol=1e-5)


def test_tiny_model_overfits_one_block(room: Callable[..., PointCloud]) -> None:
    scene = room(0, size_m=(3.0, 3.0), points_per_m2=60)
    block = sample_block(scene.xyz, scene.label, points=256, rng=np.random.default_rng(0))
    xyz = torch.from_numpy(block.xyz)[None]
    label = torch.from_numpy(block.label)[None]
    torch.manual_seed(0)
    model = build_model(5, ModelConfig(embed_dim=32, attention_layers=2, fuse_dim=64, head_dims=(64, 32), dropout=0.0))
    optimizer = torch.optim.Adam(model.parameters(), lr=5e-3)
    start_accuracy = accuracy = 0.0
    for step in range(200):
        model.train()
        loss, _ = compute_loss(model(xyz), label)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        commit_batch_statistics(model)
        if step % 10 == 0:
            model.eval()
            with torch.no_grad():
                accuracy = float((model(xyz).argmax(dim=-1) == label).float().mean())
            start_accuracy = accuracy if step == 0 else start_accuracy
            if accuracy >= 0.97:
                break

    assert len(np.unique(block.label)) == 5  # a real task: all five classes in the block
    assert start_accuracy < 0.7
    assert accuracy >= 0.97, f"tiny PCT reached only {accuracy:.3f} accuracy on one block in 200 steps"


def test_offset_attention_does_not_overflow_float16_when_every_query_attends_one_key() -> None:
    # every query gives most weight to point 0: its column sum is about 0.8 N = 1600, and
    # values of 50 make the un-normalised attended value 8e4, beyond float16's 65504
    torch.manual_seed(5)
    layer = OffsetAttention(16).eval()
    points = 2048
    with torch.no_grad():
        layer.qk.weight.zero_()
        layer.qk.weight[0, 0, 0] = 1.0
        layer.v.weight.zero_()
        layer.v.bias.fill_(50.0)
    x = torch.zeros(1, 16, points)
    x[0, 0, :] = 1.0
    x[0, 0, 0] = 10.0

    reference = layer(x, None)
    with torch.autocast("cpu", dtype=torch.float16):
        mixed = layer(x, None)

    assert torch.isfinite(mixed).all()
    torch.testing.assert_close(mixed.float(), reference, atol=0.1, rtol=5e-3)


def test_batch_statistics_of_all_layers_travel_in_one_all_reduce(monkeypatch: pytest.MonkeyPatch) -> None:
    import bimscan.learn.model as model_module

    torch.manual_seed(6)
    per_layer, flat = build_model(5, TINY), build_model(5, TINY)
    flat.load_state_dict(per_layer.state_dict())
    xyz = torch.randn(2, 64, 3)
    for model in (per_layer, flat):
        model.train()(xyz)
    for norm in per_layer.modules():
        if isinstance(norm, MaskedBatchNorm1d):
            norm.commit_statistics()  # no process group: nothing to reduce
    calls: list[int] = []
    monkeypatch.setattr(model_module.dist, "is_initialized", lambda: True)
    monkeypatch.setattr(model_module.dist, "all_reduce", lambda tensor, group=None: calls.append(tensor.numel()))

    commit_batch_statistics(flat)

    norms = [m for m in flat.modules() if isinstance(m, MaskedBatchNorm1d)]
    assert calls == [sum(len(m.pending) for m in norms)]
    for a, b in zip(per_layer.state_dict().values(), flat.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, atol=0.0, rtol=0.0)
