r"""Average several ONNX networks of one interface into one ONNX file (an ensemble).

:func:`average_models` takes networks with the same single input and the same first output
(for instance two patch refiners, :class:`localization.detect.refiner.PatchRefiner`'s interface) and writes
one model that runs all of them on the shared input and returns the element-wise mean of their
outputs (an ONNX ``Mean`` node). The result is an ordinary model file, so everything that takes a
refiner path (``LearnedDetector(refiner=...)``, ``uav-struct study --refiner-model``,
``LocalizationWrapper(refiner_model=...)``) takes the ensemble unchanged; inference costs the
sum of its members. For the refiner the mean is taken over the sigmoid probabilities and the
offsets, the same as averaging the members' outputs after running them one by one (to float32
rounding).

The committed ``landmarks_active_v4_refiner.onnx`` was built this way (model card)::

    python -m uav_struct_env.training.ensemble landmarks_active_v3_refiner.onnx \
        runs/det4/refiner/refiner.onnx --out localization/detect/models/landmarks_active_v4_refiner.onnx

:func:`split_ensemble` undoes it: it writes each member back to a file of its own, so the
members of a committed ensemble need not ship beside it (``--split``)::

    python -m uav_struct_env.training.ensemble --split \
        localization/detect/models/landmarks_active_v4_refiner.onnx --out runs/v4_members
    # runs/v4_members/m0/landmarks_active_v3_refiner.onnx, runs/v4_members/m1/refiner.onnx
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import onnx
from onnx import compose, helper

__all__ = ["average_models", "split_ensemble"]

#: How :func:`average_models` names its members in the model's ``doc_string``.
_MEMBERS = "mean of: "


def _interface(path: Path, model: onnx.ModelProto) -> dict[str, bytes | tuple]:
    """What members must share: the input's and first output's types, the opsets."""
    graph = model.graph
    if len(graph.input) != 1:
        raise ValueError(f"{path} has inputs {[i.name for i in graph.input]}; an ensemble member "
                         "has one input")
    return {"input": graph.input[0].type.SerializeToString(),
            "output": graph.output[0].type.SerializeToString(),
            "opset": tuple((o.domain, o.version) for o in model.opset_import)}


def average_models(models: Sequence[str | Path], out: str | Path) -> Path:
    """Write to ``out`` one ONNX model returning the mean of ``models``' first outputs.

    Every member must have one input and the same input type, first-output type and opsets as
    the first member. Returns the path written.

    Raises:
        ValueError: fewer than two models, a member with more than one input, or members that
            differ in interface (the first difference named). FileNotFoundError: a member file
            is missing.
    """
    paths = [Path(m) for m in models]
    if len(paths) < 2:
        raise ValueError(f"an ensemble needs at least two models, got {len(paths)}")
    for p in paths:
        if not p.is_file():
            raise FileNotFoundError(f"ONNX model not found: {p}")
    loaded = [onnx.load(str(p)) for p in paths]
    ref = _interface(paths[0], loaded[0])
    for p, m in zip(paths[1:], loaded[1:], strict=True):
        differ = [key for key, value in _interface(p, m).items() if value != ref[key]]
        if differ:
            raise ValueError(f"{p} has another {differ[0]} than {paths[0]}; an ensemble averages "
                             "models of one interface (input, output, opset)")
    shared_in = loaded[0].graph.input[0]
    nodes, inits, outputs = [], [], []
    for k, m in enumerate(loaded):
        m = compose.add_prefix(m, f"m{k}_")
        g = m.graph
        own_in = g.input[0].name
        for node in g.node:
            node.input[:] = [shared_in.name if name == own_in else name for name in node.input]
            nodes.append(node)
        inits.extend(g.initializer)
        outputs.append(g.output[0].name)
    first_out = loaded[0].graph.output[0]
    nodes.append(helper.make_node("Mean", outputs, [first_out.name], name="ensemble_mean"))
    graph = helper.make_graph(nodes, "ensemble", [shared_in], [first_out], initializer=inits)
    merged = helper.make_model(graph, opset_imports=list(loaded[0].opset_import),
                               producer_name="uav_struct_env.training.ensemble")
    merged.ir_version = loaded[0].ir_version
    merged.doc_string = _MEMBERS + ", ".join(p.name for p in paths)
    onnx.checker.check_model(merged)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(merged, str(out))
    return out


def _strip(name: str, prefix: str) -> str:
    return name[len(prefix):] if name.startswith(prefix) else name


def _member(ensemble: onnx.ModelProto, k: int) -> onnx.ModelProto:
    """Member ``k`` of an :func:`average_models` ensemble as a model of its own (names unprefixed)."""
    graph, prefix = ensemble.graph, f"m{k}_"
    nodes = []
    for node in graph.node[:-1]:  # the last node is the Mean
        if node.output and all(o.startswith(prefix) for o in node.output):
            own = onnx.NodeProto()
            own.CopyFrom(node)
            own.input[:] = [_strip(i, prefix) for i in node.input]
            own.output[:] = [_strip(o, prefix) for o in node.output]
            own.name = _strip(node.name, prefix)
            nodes.append(own)
    inits = []
    for tensor in graph.initializer:
        if tensor.name.startswith(prefix):
            own = onnx.TensorProto()
            own.CopyFrom(tensor)
            own.name = _strip(tensor.name, prefix)
            inits.append(own)
    output = onnx.ValueInfoProto()
    output.CopyFrom(graph.output[0])
    output.name = _strip(graph.node[-1].input[k], prefix)
    own_graph = helper.make_graph(nodes, graph.name, [graph.input[0]], [output], initializer=inits)
    model = helper.make_model(own_graph, opset_imports=list(ensemble.opset_import))
    model.ir_version = ensemble.ir_version
    onnx.checker.check_model(model)
    return model


def split_ensemble(model: str | Path, out_dir: str | Path) -> list[Path]:
    """Write each member of an ensemble made by :func:`average_models` to a file of its own.

    Member ``k`` goes to ``out_dir/m{k}/NAME`` under the file name it had (the ensemble records
    them), so :func:`average_models` on the returned paths, in order, writes ``model`` again byte
    for byte. A member computes what it computed in the ensemble; its file is not the original's
    bytes (the exporter's metadata is not kept).

    Raises:
        FileNotFoundError: ``model`` is missing. ValueError: it is not such an ensemble.
    """
    path = Path(model)
    if not path.is_file():
        raise FileNotFoundError(f"ONNX model not found: {path}")
    ensemble = onnx.load(str(path))
    nodes = ensemble.graph.node
    if (not ensemble.doc_string.startswith(_MEMBERS) or not nodes or nodes[-1].op_type != "Mean"
            or len(nodes[-1].input) != len(ensemble.doc_string.split(", "))):
        raise ValueError(f"{path} is not an ensemble written by average_models (no final Mean node "
                         f"over the members its doc_string names)")
    names = ensemble.doc_string[len(_MEMBERS):].split(", ")
    out = []
    for k, name in enumerate(names):
        target = Path(out_dir) / f"m{k}" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        onnx.save(_member(ensemble, k), str(target))
        out.append(target)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="ONNX files of one interface (two or more); with --split, "
                    "one ensemble")
    ap.add_argument("--out", required=True,
                    help="the ensemble's ONNX file; with --split, the members' folder")
    ap.add_argument("--split", action="store_true",
                    help="write the members of the ensemble given, each to OUT/m<k>/<its file name>")
    a = ap.parse_args(argv)
    if a.split and len(a.models) != 1:
        ap.error(f"--split takes one ensemble, got {len(a.models)} files")
    try:
        if a.split:
            paths = split_ensemble(a.models[0], a.out)
            print(f"wrote {len(paths)} members: " + ", ".join(str(p) for p in paths))
            return 0
        path = average_models(a.models, a.out)
    except (ValueError, FileNotFoundError) as e:
        ap.error(str(e))
    print(f"wrote {path}: the mean of {len(a.models)} models")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
