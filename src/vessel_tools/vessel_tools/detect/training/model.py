"""A trainable YOLOX built from an ONNX export, with a new class head, and its export back to ONNX.

The COCO YOLOX-Nano ships only as ONNX. ``onnx2torch`` turns its graph into a ``torch.fx`` module; the last
reshapes of that graph fix the input size, so the graph is cut where each stride level's head outputs its box,
objectness and class maps, which leaves a fully convolutional network that takes any input whose sides are
multiples of 32. The 80-class convolutions are replaced by ones for the new classes, initialised from a chosen
COCO class (``boat``) so that training starts from the detector it fine-tunes.

:class:`ExportHead` puts back the layout the ONNX model had (``(1, anchors, 5 + C)``: raw grid-relative box,
sigmoid objectness, sigmoid class scores), so the exported model runs through the project's YOLOX decoder.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from torch import fx, nn

from vessel_common.errors import ModelError

STRIDES = (8, 16, 32)


@dataclass(frozen=True)
class HeadTaps:
    """The FX nodes of one stride level's head: box regression, objectness logit and the class convolution."""

    box: str
    objectness: str
    class_conv: str


def _module_of(gm: fx.GraphModule, node: fx.Node) -> nn.Module | None:
    return gm.get_submodule(node.target) if node.op == "call_module" else None


def find_head_taps(gm: fx.GraphModule) -> list[HeadTaps]:
    """Find the per-level ``concat(box, sigmoid(obj), sigmoid(cls))`` nodes of a YOLOX graph, stride 8 first."""
    taps = []
    for node in gm.graph.nodes:
        if node.op != "call_module" or type(_module_of(gm, node)).__name__ != "OnnxConcat" or len(node.args) != 3:
            continue
        box, obj_sig, cls_sig = node.args
        if not all(isinstance(a, fx.Node) for a in node.args):
            continue
        if not (isinstance(_module_of(gm, obj_sig), nn.Sigmoid) and isinstance(_module_of(gm, cls_sig), nn.Sigmoid)):
            continue
        obj, cls = obj_sig.args[0], cls_sig.args[0]
        convs = [_module_of(gm, n) for n in (box, obj, cls)]
        if not all(isinstance(c, nn.Conv2d) for c in convs):
            continue
        if convs[0].out_channels != 4 or convs[1].out_channels != 1:
            continue
        taps.append(HeadTaps(box.name, obj.name, cls.name))
    if len(taps) != len(STRIDES):
        raise ModelError(
            f"found {len(taps)} YOLOX head levels in the ONNX graph, expected {len(STRIDES)}: the training "
            "command fine-tunes YOLOX exports (box, objectness and class maps concatenated per stride level)"
        )
    return taps


class TrainableYolox(nn.Module):
    """YOLOX body from an ONNX file, returning raw ``(box, objectness logit, class logits)`` maps per level."""

    def __init__(self, onnx_path: str | Path, class_names: tuple[str, ...], init_class: int = 8):
        super().__init__()
        from onnx2torch import convert

        path = Path(onnx_path)
        if not path.is_file():
            raise ModelError(f"start model {path} not found: give the COCO YOLOX-Nano ONNX with --init-model")
        try:
            gm = convert(str(path))
        except Exception as error:  # onnx2torch raises untyped errors for graphs it cannot convert
            raise ModelError(f"cannot convert {path} to PyTorch: {str(error)[:200]}") from None
        taps = find_head_taps(gm)
        nodes = {n.name: n for n in gm.graph.nodes}
        graph = gm.graph
        output = next(n for n in graph.nodes if n.op == "output")
        old_class_convs = [gm.get_submodule(nodes[tap.class_conv].target) for tap in taps]
        outs = []
        for tap in taps:
            outs += [nodes[tap.box], nodes[tap.objectness], nodes[tap.class_conv].args[0]]
        output.args = (tuple(outs),)
        graph.eliminate_dead_code()
        gm.recompile()
        gm.delete_all_unused_submodules()
        self.body = gm
        self.class_names = tuple(class_names)
        self.class_convs = nn.ModuleList()
        for old in old_class_convs:
            new = nn.Conv2d(old.in_channels, len(class_names), old.kernel_size, old.stride, old.padding)
            with torch.no_grad():
                row = min(max(int(init_class), 0), old.out_channels - 1)
                new.weight.copy_(old.weight[row : row + 1].repeat(len(class_names), 1, 1, 1))
                new.bias.copy_(old.bias[row : row + 1].repeat(len(class_names)))
            self.class_convs.append(new)

    @property
    def num_classes(self) -> int:
        """Number of output classes."""
        return len(self.class_names)

    def forward(self, images: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """``images`` (B, 3, H, W) BGR 0-255 -> per level ``(box (B,4,h,w), obj (B,1,h,w), cls (B,C,h,w))``."""
        if not torch.jit.is_tracing() and (images.shape[-1] % 32 or images.shape[-2] % 32):
            raise ModelError(f"network input {tuple(images.shape[-2:])} is not a multiple of 32 on each side")
        raw = self.body(images)
        levels = []
        for level, conv in enumerate(self.class_convs):
            box, obj, features = raw[3 * level : 3 * level + 3]
            levels.append((box, obj, conv(features)))
        return levels


def flatten_levels(levels, strides=STRIDES):
    """Per-level maps -> raw boxes, objectness and class logits per anchor, with each anchor's cell and stride.

    Shapes: ``(B, A, 4)``, ``(B, A)``, ``(B, A, C)``, the grid ``(A, 2)`` (cell x, y) and ``(A,)``; stride 8 first.
    """
    boxes, objs, clss, grids, stride_of = [], [], [], [], []
    for (box, obj, cls), stride in zip(levels, strides, strict=True):
        b, _, h, w = box.shape
        boxes.append(box.flatten(2).transpose(1, 2))
        objs.append(obj.flatten(1))
        clss.append(cls.flatten(2).transpose(1, 2))
        ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
        grids.append(torch.stack([xs.flatten(), ys.flatten()], 1).to(box.dtype))
        stride_of.append(torch.full((h * w,), float(stride), dtype=box.dtype))
    return torch.cat(boxes, 1), torch.cat(objs, 1), torch.cat(clss, 1), torch.cat(grids, 0), torch.cat(stride_of, 0)


def decode_boxes(raw_boxes: torch.Tensor, grids: torch.Tensor, strides: torch.Tensor) -> torch.Tensor:
    """Raw YOLOX regression -> ``(B, A, 4)`` centre x, centre y, width, height in input pixels."""
    s = strides[None, :, None]
    centre = (raw_boxes[..., :2] + grids[None]) * s
    size = torch.exp(raw_boxes[..., 2:].clamp(max=20.0)) * s
    return torch.cat([centre, size], -1)


class ExportHead(nn.Module):
    """The trained network with the ONNX YOLOX output layout: ``(1, anchors, 4 + 1 + C)``."""

    def __init__(self, model: TrainableYolox):
        super().__init__()
        self.model = model

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """``(1, 3, H, W)`` -> ``(1, anchors, 5 + C)``."""
        rows = []
        for box, obj, cls in self.model(images):
            level = torch.cat([box, torch.sigmoid(obj), torch.sigmoid(cls)], 1)
            rows.append(level.flatten(2))
        return torch.cat(rows, 2).transpose(1, 2)


def export_onnx(model: TrainableYolox, path: str | Path, input_hw: tuple[int, int]) -> None:
    """Write the model as ONNX (opset 17, batch 1), input ``images``, output ``output``.

    The input height and width are left free (the network is convolutional to its output), with ``input_hw``
    recorded as the usual size, the size the detector runs it at.
    """
    head = ExportHead(model).eval()
    dummy = torch.full((1, 3, *input_hw), 114.0)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        torch.onnx.export(head, (dummy,), str(path), input_names=["images"], output_names=["output"],
                          opset_version=17, dynamo=False,
                          dynamic_axes={"images": {2: "height", 3: "width"}, "output": {1: "anchors"}})
    record_input_size(path, input_hw)


def record_input_size(path: str | Path, input_hw: tuple[int, int]) -> None:
    """Free the input height and width of the ONNX file at ``path`` and record ``input_hw`` as its usual size.

    Also frees a model exported with a fixed size, whose graph computes its reshapes from the input's shape:
    the weights and operators stay as they are. The detector reads the size back (``input_size`` metadata).
    """
    import onnx

    from vessel_detect.detector import INPUT_SIZE_METADATA_KEY

    graph = onnx.load(str(path))
    dims = graph.graph.input[0].type.tensor_type.shape.dim
    dims[2].dim_param, dims[3].dim_param = "height", "width"
    output_dims = graph.graph.output[0].type.tensor_type.shape.dim
    if len(output_dims) == 3:
        output_dims[1].dim_param = "anchors"
    del graph.graph.value_info[:]
    kept = [p for p in graph.metadata_props if p.key != INPUT_SIZE_METADATA_KEY]
    del graph.metadata_props[:]
    graph.metadata_props.extend(kept)
    entry = graph.metadata_props.add()
    entry.key, entry.value = INPUT_SIZE_METADATA_KEY, f"{int(input_hw[1])}x{int(input_hw[0])}"
    onnx.checker.check_model(graph)
    onnx.save(graph, str(path))
