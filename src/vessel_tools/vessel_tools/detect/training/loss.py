"""The YOLOX training loss: SimOTA label assignment, IoU loss, objectness and class BCE, ignore regions.

As in YOLOX (Ge et al. 2021): an anchor point is a candidate for a ground-truth box when its centre lies in
the box or within ``centre_radius`` strides of the box centre; each box takes its ``k`` cheapest candidates,
``k`` being the rounded sum of its 10 best IoUs, with the cost ``class BCE + 3 (-log IoU)`` (plus a large
penalty outside box-and-centre); an anchor claimed by two boxes goes to the cheaper. Objectness is trained on
every anchor except those whose centre lies inside an ignore region (boxes that may be a vessel but whose
label is not known) and that no box claimed.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F  # noqa: N812 - PyTorch's own convention

from vessel_tools.detect.training.model import decode_boxes, flatten_levels


@dataclass
class LossParts:
    """The loss and its parts (already normalised by the number of foreground anchors)."""

    total: torch.Tensor
    box: float
    objectness: float
    classes: float
    foreground: int


def pairwise_iou_cxcywh(a: torch.Tensor, b_xyxy: torch.Tensor) -> torch.Tensor:
    """IoU of every predicted ``(cx, cy, w, h)`` box in ``a`` (A, 4) with every ``b`` (G, 4) xyxy: (G, A)."""
    ax1, ay1 = a[:, 0] - a[:, 2] / 2, a[:, 1] - a[:, 3] / 2
    ax2, ay2 = a[:, 0] + a[:, 2] / 2, a[:, 1] + a[:, 3] / 2
    ix1 = torch.maximum(ax1[None], b_xyxy[:, None, 0])
    iy1 = torch.maximum(ay1[None], b_xyxy[:, None, 1])
    ix2 = torch.minimum(ax2[None], b_xyxy[:, None, 2])
    iy2 = torch.minimum(ay2[None], b_xyxy[:, None, 3])
    inter = (ix2 - ix1).clamp(min=0) * (iy2 - iy1).clamp(min=0)
    area_a = (a[:, 2] * a[:, 3])[None]
    area_b = ((b_xyxy[:, 2] - b_xyxy[:, 0]) * (b_xyxy[:, 3] - b_xyxy[:, 1]))[:, None]
    return inter / (area_a + area_b - inter + 1e-9)


def simota_assign(pred_boxes, obj_logits, cls_logits, centres, strides, gt_boxes, gt_classes,
                  centre_radius: float = 2.5, top_candidates: int = 10):
    """Return ``(foreground mask (A,), matched gt index (A,), IoU of each foreground anchor with its gt)``."""
    num_anchors = pred_boxes.shape[0]
    num_gt = gt_boxes.shape[0]
    cx, cy = centres[:, 0], centres[:, 1]
    in_box = (cx[None] > gt_boxes[:, None, 0]) & (cx[None] < gt_boxes[:, None, 2]) & (
        cy[None] > gt_boxes[:, None, 1]) & (cy[None] < gt_boxes[:, None, 3])
    gcx = (gt_boxes[:, 0] + gt_boxes[:, 2]) / 2
    gcy = (gt_boxes[:, 1] + gt_boxes[:, 3]) / 2
    radius = centre_radius * strides[None]
    in_centre = ((cx[None] - gcx[:, None]).abs() < radius) & ((cy[None] - gcy[:, None]).abs() < radius)
    candidate = (in_box | in_centre).any(0)
    fg = torch.zeros(num_anchors, dtype=torch.bool)
    matched = torch.zeros(num_anchors, dtype=torch.long)
    ious_out = torch.zeros(num_anchors)
    if not candidate.any():
        return fg, matched, ious_out
    idx = torch.nonzero(candidate).squeeze(1)
    with torch.no_grad():
        iou = pairwise_iou_cxcywh(pred_boxes[idx], gt_boxes)
        probs = (torch.sigmoid(cls_logits[idx]) * torch.sigmoid(obj_logits[idx])[:, None]).sqrt()
        onehot = F.one_hot(gt_classes, cls_logits.shape[1]).float()
        cls_cost = F.binary_cross_entropy(
            probs[None].expand(num_gt, -1, -1).clamp(1e-6, 1 - 1e-6),
            onehot[:, None].expand(-1, idx.numel(), -1), reduction="none").sum(-1)
        both = in_box[:, idx] & in_centre[:, idx]
        cost = cls_cost + 3.0 * -torch.log(iou + 1e-8) + 1e5 * (~both).float()
        k = torch.clamp(torch.topk(iou, min(top_candidates, idx.numel()), dim=1).values.sum(1).int(), min=1)
        assign = torch.zeros_like(cost, dtype=torch.bool)
        for g in range(num_gt):
            chosen = torch.topk(cost[g], int(min(k[g], idx.numel())), largest=False).indices
            assign[g, chosen] = True
        multiple = assign.sum(0) > 1
        if multiple.any():
            best = cost[:, multiple].argmin(0)
            assign[:, multiple] = False
            assign[best, torch.nonzero(multiple).squeeze(1)] = True
        claimed = assign.any(0)
        fg[idx[claimed]] = True
        matched[idx[claimed]] = assign[:, claimed].float().argmax(0)
        ious_out[idx[claimed]] = (iou * assign.float()).sum(0)[claimed]
    return fg, matched, ious_out


def inside_any(centres: torch.Tensor, boxes: torch.Tensor) -> torch.Tensor:
    """(A,) True where an anchor centre lies inside one of ``boxes`` (M, 4)."""
    if boxes.numel() == 0:
        return torch.zeros(centres.shape[0], dtype=torch.bool)
    cx, cy = centres[:, 0:1], centres[:, 1:2]
    return ((cx > boxes[None, :, 0]) & (cx < boxes[None, :, 2]) & (cy > boxes[None, :, 1]) & (
        cy < boxes[None, :, 3])).any(1)


def yolox_loss(levels, targets, box_weight: float = 5.0) -> LossParts:
    """The loss of a batch; ``targets``: per image ``(boxes (G, 4) xyxy, classes (G,), ignore (M, 4))``."""
    raw_boxes, obj_logits, cls_logits, grids, strides = flatten_levels(levels)
    pred = decode_boxes(raw_boxes, grids, strides)
    centres = (grids + 0.5) * strides[:, None]
    box_losses, obj_losses, cls_losses = [], [], []
    num_fg = 0
    for b, (gt_boxes, gt_classes, ignore) in enumerate(targets):
        obj_target = torch.zeros(obj_logits.shape[1])
        weight = torch.ones(obj_logits.shape[1])
        if gt_boxes.numel():
            fg, matched, ious = simota_assign(pred[b], obj_logits[b], cls_logits[b], centres, strides,
                                              gt_boxes, gt_classes)
        else:
            fg = torch.zeros(obj_logits.shape[1], dtype=torch.bool)
        weight[inside_any(centres, ignore) & ~fg] = 0.0
        if fg.any():
            obj_target[fg] = 1.0
            boxes_fg = pred[b][fg]
            gts = gt_boxes[matched[fg]]
            iou = torch.diagonal(pairwise_iou_cxcywh(boxes_fg, gts))
            box_losses.append((1.0 - iou**2).sum())
            cls_target = F.one_hot(gt_classes[matched[fg]], cls_logits.shape[2]).float() * ious[fg, None]
            cls_losses.append(F.binary_cross_entropy_with_logits(cls_logits[b][fg], cls_target,
                                                                 reduction="none").sum())
            num_fg += int(fg.sum())
        obj_losses.append((F.binary_cross_entropy_with_logits(obj_logits[b], obj_target, reduction="none")
                           * weight).sum())
    norm = max(num_fg, 1)
    zero = obj_logits.sum() * 0.0
    box = torch.stack(box_losses).sum() / norm if box_losses else zero
    obj = torch.stack(obj_losses).sum() / norm
    cls = torch.stack(cls_losses).sum() / norm if cls_losses else zero
    total = box_weight * box + obj + cls
    return LossParts(total, float(box.detach()), float(obj.detach()), float(cls.detach()), num_fg)
