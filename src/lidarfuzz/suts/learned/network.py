"""PillarNet: a PointPillars-style 3D detector in pure PyTorch (no compiled ops).

Pillar feature network → scatter to a bird's-eye pseudo-image → 2D CNN backbone with
an upsampling neck → a centre-based head (CenterPoint-style heat map per class, plus
offset, height, size and heading regressed at each centre). Everything runs on the CPU
or a GPU with stock PyTorch operators: pillars are formed with ``torch.unique`` and
reduced with ``scatter_reduce`` (dynamic pillars, as in dynamic-voxel PointPillars: no
cap on points per pillar, no random dropping), so the same frame always gives the same
pseudo-image.

Coordinates are the LiDAR frame (x forward, y left, z up); boxes are
``[x, y, z, l, w, h, yaw]`` with the centre origin, as everywhere in lidarfuzz.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import Tensor, nn

#: Regression channels of the head, in order.
REGRESSION = ("dx", "dy", "z", "log_l", "log_w", "log_h", "sin", "cos")


@dataclass(frozen=True)
class PillarConfig:
    """Geometry and capacity of the network (saved with the weights).

    Attributes:
        classes: Output classes, one heat-map channel each.
        x_range, y_range, z_range: The box of LiDAR space the network sees (metres).
        pillar: Pillar edge (metres); the pseudo-image has one cell per pillar.
        stride: Output stride of the head relative to the pseudo-image.
        pillar_channels: Width of the pillar feature network.
        block_channels, block_layers: The backbone's three stages (each halves the resolution).
        neck_channels: Channels of each stage after upsampling to the head's stride.
        head_channels: Width of the shared head convolution.
    """

    classes: tuple[str, ...] = ("Car", "Pedestrian", "Cyclist")
    x_range: tuple[float, float] = (0.0, 57.6)
    y_range: tuple[float, float] = (-38.4, 38.4)
    z_range: tuple[float, float] = (-3.0, 1.0)
    pillar: float = 0.2
    stride: int = 2
    pillar_channels: int = 32
    block_channels: tuple[int, int, int] = (32, 64, 128)
    block_layers: tuple[int, int, int] = (3, 4, 4)
    neck_channels: int = 32
    head_channels: int = 64
    mean_sizes: dict[str, tuple[float, float, float]] = field(
        default_factory=lambda: {"Car": (3.9, 1.6, 1.56), "Pedestrian": (0.8, 0.6, 1.73), "Cyclist": (1.76, 0.6, 1.73)}
    )

    @property
    def grid(self) -> tuple[int, int]:
        """Pseudo-image size (rows along y, columns along x)."""
        nx = round((self.x_range[1] - self.x_range[0]) / self.pillar)
        ny = round((self.y_range[1] - self.y_range[0]) / self.pillar)
        return ny, nx

    @property
    def out_grid(self) -> tuple[int, int]:
        ny, nx = self.grid
        return ny // self.stride, nx // self.stride

    @property
    def cell(self) -> float:
        """Edge of one output cell (metres)."""
        return self.pillar * self.stride

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> PillarConfig:
        values = dict(data)
        for key in ("classes", "x_range", "y_range", "z_range", "block_channels", "block_layers"):
            if key in values:
                values[key] = tuple(values[key])
        if "mean_sizes" in values:
            values["mean_sizes"] = {k: tuple(v) for k, v in values["mean_sizes"].items()}
        return cls(**values)


def _conv(cin: int, cout: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU()]


class PillarFeatureNet(nn.Module):
    """Points → per-pillar features → a (B, C, H, W) pseudo-image.

    Each point gets 9 features (x, y, z, intensity, offsets to its pillar's point mean,
    offsets to the pillar centre in x and y), a shared linear layer + BN + ReLU, and each
    pillar keeps the channel-wise maximum over its points.
    """

    def __init__(self, config: PillarConfig) -> None:
        super().__init__()
        self.config = config
        self.linear = nn.Linear(9, config.pillar_channels, bias=False)
        self.norm = nn.BatchNorm1d(config.pillar_channels)
        self.relu = nn.ReLU()

    def forward(self, points: Tensor, batch_index: Tensor, batch_size: int) -> Tensor:
        cfg = self.config
        ny, nx = cfg.grid
        ix = torch.floor((points[:, 0] - cfg.x_range[0]) / cfg.pillar).long()
        iy = torch.floor((points[:, 1] - cfg.y_range[0]) / cfg.pillar).long()
        keep = (
            (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
            & (points[:, 2] >= cfg.z_range[0]) & (points[:, 2] < cfg.z_range[1])
        )
        points, ix, iy, batch_index = points[keep], ix[keep], iy[keep], batch_index[keep]
        canvas = points.new_zeros(batch_size * ny * nx, cfg.pillar_channels)
        if points.shape[0] == 0:
            return canvas.view(batch_size, ny, nx, -1).permute(0, 3, 1, 2).contiguous()
        flat = (batch_index * ny + iy) * nx + ix
        cells, inverse = torch.unique(flat, return_inverse=True)
        count = torch.zeros(cells.shape[0], device=points.device, dtype=points.dtype)
        count.index_add_(0, inverse, torch.ones_like(points[:, 0]))
        total = torch.zeros(cells.shape[0], 3, device=points.device, dtype=points.dtype)
        total.index_add_(0, inverse, points[:, :3])
        mean = total / count[:, None]
        centre_x = (ix.to(points.dtype) + 0.5) * cfg.pillar + cfg.x_range[0]
        centre_y = (iy.to(points.dtype) + 0.5) * cfg.pillar + cfg.y_range[0]
        features = torch.cat(
            [
                points[:, :4],
                points[:, :3] - mean[inverse],
                (points[:, 0] - centre_x)[:, None],
                (points[:, 1] - centre_y)[:, None],
            ],
            dim=1,
        )
        per_point = self.relu(self.norm(self.linear(features)))
        pillars = torch.zeros(cells.shape[0], cfg.pillar_channels, device=points.device, dtype=points.dtype)
        pillars = pillars.scatter_reduce(
            0, inverse[:, None].expand_as(per_point), per_point, reduce="amax", include_self=False
        )
        canvas[cells] = pillars
        return canvas.view(batch_size, ny, nx, -1).permute(0, 3, 1, 2).contiguous()


class Backbone(nn.Module):
    """Three stages at strides 2, 4, 8 of the pseudo-image, upsampled to the head's stride and concatenated."""

    def __init__(self, config: PillarConfig) -> None:
        super().__init__()
        channels = (config.pillar_channels, *config.block_channels)
        self.blocks = nn.ModuleList()
        for stage in range(3):
            layers = _conv(channels[stage], channels[stage + 1], stride=2)
            for _ in range(config.block_layers[stage] - 1):
                layers += _conv(channels[stage + 1], channels[stage + 1])
            self.blocks.append(nn.Sequential(*layers))
        self.ups = nn.ModuleList()
        for stage in range(3):
            scale = 2 ** (stage + 1) // config.stride
            cin, cout = config.block_channels[stage], config.neck_channels
            if scale == 1:
                up: nn.Module = nn.Conv2d(cin, cout, 1, bias=False)
            else:
                up = nn.ConvTranspose2d(cin, cout, scale, stride=scale, bias=False)
            self.ups.append(nn.Sequential(up, nn.BatchNorm2d(cout), nn.ReLU()))

    def forward(self, image: Tensor) -> Tensor:
        outs = []
        x = image
        for block, up in zip(self.blocks, self.ups, strict=True):
            x = block(x)
            outs.append(up(x))
        return torch.cat(outs, dim=1)


class CenterHead(nn.Module):
    """A shared 3×3 convolution, then a heat map per class and the box regression."""

    def __init__(self, config: PillarConfig) -> None:
        super().__init__()
        cin = 3 * config.neck_channels
        self.shared = nn.Sequential(*_conv(cin, config.head_channels))
        self.heatmap = nn.Conv2d(config.head_channels, len(config.classes), 1)
        self.regression = nn.Conv2d(config.head_channels, len(REGRESSION), 1)
        bias = self.heatmap.bias
        assert bias is not None  # nn.Conv2d has one unless built with bias=False
        nn.init.constant_(bias, -2.19)  # prior 0.1, as CenterNet

    def forward(self, features: Tensor) -> tuple[Tensor, Tensor]:
        x = self.shared(features)
        return self.heatmap(x), self.regression(x)


class PillarNet(nn.Module):
    """The whole network: ``forward(points, batch_index, batch_size) -> (heat-map logits, regression)``.

    ``points`` is a P×4 tensor (x, y, z, intensity) of every frame in the batch and
    ``batch_index`` the frame of each point.
    """

    def __init__(self, config: PillarConfig | None = None) -> None:
        super().__init__()
        self.config = config or PillarConfig()
        self.pillars = PillarFeatureNet(self.config)
        self.backbone = Backbone(self.config)
        self.head = CenterHead(self.config)

    def forward(self, points: Tensor, batch_index: Tensor, batch_size: int) -> tuple[Tensor, Tensor]:
        image = self.pillars(points, batch_index, batch_size)
        return self.head(self.backbone(image))

    def coverage_layers(self) -> list[str]:
        """The post-activation modules neuron coverage watches: every ReLU of the backbone,
        neck and head (batch-first feature maps). The pillar network's ReLU works on points,
        not frames, so it is left out."""
        return [name for name, module in self.named_modules() if isinstance(module, nn.ReLU) and name != "pillars.relu"]


def decode(
    heatmap: Tensor,
    regression: Tensor,
    config: PillarConfig,
    *,
    top_k: int = 100,
    score_threshold: float = 0.1,
) -> list[tuple[Tensor, Tensor, Tensor]]:
    """Peaks of each frame's heat map → (boxes K×7, scores K, class indices K) per frame.

    A peak is a cell that equals the maximum of its 3×3 neighbourhood (CenterNet's
    max-pool suppression); rotated NMS on the boxes comes after (:func:`rotated_nms`).
    """
    batch, _, height, width = heatmap.shape
    scores = torch.sigmoid(heatmap)
    peaks = scores == nn.functional.max_pool2d(scores, 3, stride=1, padding=1)
    scores = scores * peaks
    flat = scores.view(batch, -1)
    k = min(top_k, flat.shape[1])
    top_scores, top_index = flat.topk(k, dim=1)
    classes = top_index // (height * width)
    cell = top_index % (height * width)
    row = (cell // width).to(heatmap.dtype)
    col = (cell % width).to(heatmap.dtype)
    reg = regression.view(batch, len(REGRESSION), -1)
    gathered = reg.gather(2, cell[:, None, :].expand(-1, len(REGRESSION), -1))  # B×8×K
    x = (col + gathered[:, 0]) * config.cell + config.x_range[0]
    y = (row + gathered[:, 1]) * config.cell + config.y_range[0]
    z = gathered[:, 2]
    dims = torch.exp(gathered[:, 3:6].clamp(max=5.0))
    yaw = torch.atan2(gathered[:, 6], gathered[:, 7])
    boxes = torch.stack([x, y, z, dims[:, 0], dims[:, 1], dims[:, 2], yaw], dim=2)
    out = []
    for b in range(batch):
        keep = top_scores[b] >= score_threshold
        out.append((boxes[b][keep], top_scores[b][keep], classes[b][keep]))
    return out


def gaussian_radius(length: Tensor, width: Tensor, min_overlap: float = 0.1) -> Tensor:
    """CornerNet's radius (in cells) within which a shifted box keeps ``min_overlap`` IoU with the true one."""
    h, w = length, width
    b1 = h + w
    c1 = w * h * (1 - min_overlap) / (1 + min_overlap)
    r1 = (b1 + torch.sqrt(b1**2 - 4 * c1)) / 2
    b2 = 2 * (h + w)
    c2 = (1 - min_overlap) * w * h
    r2 = (b2 + torch.sqrt(b2**2 - 16 * c2)) / 2
    a3 = 4 * min_overlap
    b3 = -2 * min_overlap * (h + w)
    c3 = (min_overlap - 1) * w * h
    r3 = (b3 + torch.sqrt(b3**2 - 4 * a3 * c3)) / 2
    return torch.minimum(torch.minimum(r1, r2), r3)


def build_targets(
    boxes: Tensor, classes: Tensor, batch_index: Tensor, batch_size: int, config: PillarConfig, *, min_radius: int = 2
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Training targets for M boxes: (heat map B×C×H×W, flat cell index M, regression M×8, valid M).

    Every box draws a Gaussian (σ = diameter / 6, CenterNet's radius rule) on its class's
    heat map at its centre cell, keeping the maximum where Gaussians overlap; the
    regression target sits at the centre cell. Boxes whose centre falls outside the grid
    are not valid.
    """
    height, width = config.out_grid
    n_classes = len(config.classes)
    device, dtype = boxes.device, boxes.dtype
    heatmap = torch.zeros(batch_size * n_classes * height * width, device=device, dtype=dtype)
    if boxes.shape[0] == 0:
        empty = torch.zeros(0, device=device, dtype=torch.long)
        return (heatmap.view(batch_size, n_classes, height, width), empty,
                boxes.new_zeros(0, len(REGRESSION)), empty.bool())
    gx = (boxes[:, 0] - config.x_range[0]) / config.cell
    gy = (boxes[:, 1] - config.y_range[0]) / config.cell
    col, row = torch.floor(gx).long(), torch.floor(gy).long()
    valid = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    radius = gaussian_radius(boxes[:, 3] / config.cell, boxes[:, 4] / config.cell).floor().clamp(min=min_radius)
    max_r = int(radius.max().item()) if valid.any() else min_radius
    offsets = torch.arange(-max_r, max_r + 1, device=device)
    dy, dx = torch.meshgrid(offsets, offsets, indexing="ij")
    dx, dy = dx.reshape(-1), dy.reshape(-1)
    sigma = (2 * radius + 1) / 6
    values = torch.exp(-(dx[None].to(dtype) ** 2 + dy[None].to(dtype) ** 2) / (2 * sigma[:, None] ** 2))
    cols, rows = col[:, None] + dx[None], row[:, None] + dy[None]
    inside = (
        (dx[None].abs() <= radius[:, None]) & (dy[None].abs() <= radius[:, None])
        & (cols >= 0) & (cols < width) & (rows >= 0) & (rows < height) & valid[:, None]
    )
    plane = batch_index * n_classes + classes
    index = ((plane[:, None] * height + rows) * width + cols)[inside]
    heatmap = heatmap.scatter_reduce(0, index, values[inside], reduce="amax", include_self=True)
    cell = (row.clamp(0, height - 1) * width + col.clamp(0, width - 1)) + batch_index * height * width
    mean = torch.tensor([config.mean_sizes.get(c, (1.0, 1.0, 1.0)) for c in config.classes], device=device, dtype=dtype)
    sizes = boxes[:, 3:6].clamp(min=1e-3)
    regression = torch.stack(
        [
            gx - col, gy - row, boxes[:, 2],
            *torch.log(sizes / mean[classes]).unbind(1),
            torch.sin(boxes[:, 6]), torch.cos(boxes[:, 6]),
        ],
        dim=1,
    )
    return heatmap.view(batch_size, n_classes, height, width), cell, regression, valid


def focal_loss(logits: Tensor, target: Tensor, alpha: float = 2.0, beta: float = 4.0) -> Tensor:
    """CenterNet's penalty-reduced focal loss, summed and divided by the number of peaks."""
    prob = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    positive = target.eq(1.0)
    pos_loss = -torch.log(prob) * (1 - prob) ** alpha * positive
    neg_loss = -torch.log(1 - prob) * prob**alpha * (1 - target) ** beta * (~positive)
    n_pos = positive.sum().clamp(min=1)
    return (pos_loss.sum() + neg_loss.sum()) / n_pos


def detection_loss(
    heatmap_logits: Tensor,
    regression: Tensor,
    boxes: Tensor,
    classes: Tensor,
    box_batch: Tensor,
    config: PillarConfig,
    regression_weight: float = 0.25,
) -> tuple[Tensor, dict[str, float]]:
    """Focal loss on the heat maps plus L1 on the regression at every box centre."""
    batch_size = heatmap_logits.shape[0]
    target, cell, reg_target, valid = build_targets(boxes, classes, box_batch, batch_size, config)
    hm_loss = focal_loss(heatmap_logits, target)
    if valid.any():
        flat = regression.permute(0, 2, 3, 1).reshape(-1, len(REGRESSION))
        pred = flat[cell[valid]]
        # the mean-size prior enters through the log-size target; decoding adds it back
        reg_loss = nn.functional.l1_loss(pred, reg_target[valid], reduction="mean") * len(REGRESSION)
    else:
        reg_loss = regression.sum() * 0.0
    loss = hm_loss + regression_weight * reg_loss
    return loss, {"heatmap": float(hm_loss.detach()), "regression": float(reg_loss.detach())}


def log_mean_sizes(config: PillarConfig, device: torch.device | str = "cpu") -> Tensor:
    """Per-class log of the mean size (C×3), the prior the size regression is relative to."""
    return torch.log(torch.tensor([config.mean_sizes.get(c, (1.0, 1.0, 1.0)) for c in config.classes], device=device))


def apply_size_prior(boxes: Tensor, classes: Tensor, config: PillarConfig) -> Tensor:
    """Decoded sizes are relative to each class's mean size; multiply it back in."""
    if boxes.shape[0] == 0:
        return boxes
    mean = torch.exp(log_mean_sizes(config, boxes.device))[classes]
    return torch.cat([boxes[:, :3], boxes[:, 3:6] * mean, boxes[:, 6:]], dim=1)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


__all__ = [
    "REGRESSION",
    "PillarConfig",
    "PillarNet",
    "apply_size_prior",
    "build_targets",
    "count_parameters",
    "decode",
    "detection_loss",
    "focal_loss",
    "gaussian_radius",
]
