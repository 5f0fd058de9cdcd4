"""Start a detector network from exported ONNX weights, to fine-tune it (PyTorch, CPU).

The committed weights of the learned detector exist only as ONNX graphs, exported in eval mode
with every batch norm folded into the convolution before it. :func:`load_onnx_weights` copies
such a graph into a fresh :class:`~uav_struct_env.training.train_detector.KeypointNet` or
:class:`~uav_struct_env.training.train_refiner.PatchNet`: the graph's ``Conv`` and ``Gemm``
nodes, in graph order, go to the module's ``Conv2d`` and ``Linear`` layers in the order its
forward pass calls them. A folded convolution's bias goes to the batch norm after it, which
becomes an identity (mean 0, variance ``1 - eps``, scale 1) and is replaced by a
:class:`FrozenBatchNorm2d`: it stays in eval mode while its scale and shift train, since the
statistics of the original training data are folded into the weights and a fine-tuning batch of
one building could not re-estimate them. The copy is checked against the graph in ONNX Runtime.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from torch import nn

from localization.detect.onnx_net import OnnxNet

__all__ = ["FrozenBatchNorm2d", "load_onnx_weights"]

#: Largest difference allowed between the loaded network and the ONNX graph on one input.
MATCH_TOLERANCE = 1e-3


class FrozenBatchNorm2d(nn.BatchNorm2d):
    """A batch norm that always normalizes with its stored statistics and never updates them.

    ``train()`` leaves it in eval mode; its affine scale and shift are still trained.
    """

    def train(self, mode: bool = True) -> FrozenBatchNorm2d:
        """Stay in eval mode whatever ``mode`` is."""
        return super().train(False)


def _graph_layers(path: Path) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``(op, weight, bias)`` of every Conv and Gemm node of the graph at ``path``, in order."""
    graph = onnx.load(str(path)).graph
    inits = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    layers = []
    for node in graph.node:
        if node.op_type not in ("Conv", "Gemm"):
            continue
        if len(node.input) < 3 or node.input[1] not in inits or node.input[2] not in inits:
            raise ValueError(f"{path}: {node.op_type} node {node.name!r} has no constant weight and bias")
        weight = inits[node.input[1]]
        if node.op_type == "Gemm" and not any(a.name == "transB" and a.i == 1 for a in node.attribute):
            weight = weight.T  # nn.Linear stores (out, in)
        layers.append((node.op_type, weight, inits[node.input[2]]))
    return layers


def _call_order(model: nn.Module, example: torch.Tensor) -> list[tuple[nn.Module, nn.Module | None]]:
    """``(layer, batch norm after it or None)`` of every Conv2d / Linear, in the forward pass's order."""
    after = {}
    for module in model.modules():
        if isinstance(module, nn.Sequential):
            kids = list(module)
            for a, b in zip(kids, kids[1:], strict=False):
                if isinstance(a, nn.Conv2d) and isinstance(b, nn.BatchNorm2d):
                    after[a] = b
    order: list[nn.Module] = []
    hooks = [m.register_forward_hook(lambda m, _i, _o: order.append(m))
             for m in model.modules() if isinstance(m, (nn.Conv2d, nn.Linear))]
    try:
        with torch.no_grad():
            model.eval()(example)
    finally:
        for h in hooks:
            h.remove()
    return [(m, after.get(m)) for m in order]


def _freeze_batch_norms(model: nn.Module) -> None:
    """Replace every ``nn.BatchNorm2d`` of ``model`` by a :class:`FrozenBatchNorm2d` with its state."""
    for parent in list(model.modules()):
        for name, child in parent.named_children():
            if type(child) is nn.BatchNorm2d:
                frozen = FrozenBatchNorm2d(child.num_features, eps=child.eps)
                frozen.load_state_dict(child.state_dict())
                setattr(parent, name, frozen)


def load_onnx_weights(model: nn.Module, path: str | Path, example: torch.Tensor) -> nn.Module:
    """Copy the ONNX graph at ``path`` into ``model`` (same architecture and width); returns it.

    Args:
        model: a fresh network whose layers match the graph's.
        path: the exported ONNX file (for example a committed weight set's).
        example: an input the network takes, e.g. ``(1, 3, 64, 64)`` for the keypoint network;
            the loaded network must reproduce the graph on it within :data:`MATCH_TOLERANCE`.

    Raises:
        ValueError: the graph's layers differ in number or shape from the model's (naming both),
            or the loaded network does not reproduce the graph.
    """
    path = Path(path)
    layers = _graph_layers(path)
    modules = _call_order(model, example)
    if len(layers) != len(modules):
        raise ValueError(f"{path} has {len(layers)} Conv/Gemm layers, the {type(model).__name__} "
                         f"expected {len(modules)} (another architecture?)")
    with torch.no_grad():
        for k, ((op, weight, bias), (module, bn)) in enumerate(zip(layers, modules, strict=True)):
            if tuple(weight.shape) != tuple(module.weight.shape):
                raise ValueError(f"{path}: layer {k} ({op}) has weights {tuple(weight.shape)}, the "
                                 f"{type(model).__name__} expected {tuple(module.weight.shape)} "
                                 "(another width?)")
            module.weight.copy_(torch.from_numpy(weight.copy()))
            target = module if bn is None else bn
            target.bias.copy_(torch.from_numpy(bias.copy()))
            if bn is not None:
                bn.weight.fill_(1.0)
                bn.running_mean.zero_()
                bn.running_var.fill_(1.0 - bn.eps)
    _freeze_batch_norms(model)
    with torch.no_grad():
        got = model.eval()(example).numpy()
    err = float(np.abs(got - OnnxNet(path)(example.numpy())).max())
    if err > MATCH_TOLERANCE:
        raise ValueError(f"the weights loaded from {path} differ from its graph by {err:.2e} "
                         f"(> {MATCH_TOLERANCE:g}): the layers did not map one to one")
    return model.train()
