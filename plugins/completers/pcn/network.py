"""The PCN-style network of the ``pcn`` completer (torch; imported by training only, never at run time).

PointNet encoder (shared MLP, max-pool, the global feature concatenated back onto every point,
a second shared MLP, max-pool) of the partial points in the object frame; the class one-hot joins
the global feature; a fully connected decoder emits the coarse points; a folding step turns each
coarse point and a 2 x 2 grid offset into four dense points (Yuan et al., PCN, 3DV 2018).
"""

from __future__ import annotations

import torch
from torch import nn

from stratamap.plugins.completers.pcn.data import CLASSES, COARSE_POINTS, FOLD_GRID


def shared_mlp(sizes: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class PCN(nn.Module):
    def __init__(self, width: int = 256, fold_width: int = 128):
        super().__init__()
        classes = len(CLASSES)
        self.first = shared_mlp([3, 64, 128])
        self.second = shared_mlp([256, width, width])
        self.decoder = shared_mlp([width + classes, 512, 512, COARSE_POINTS * 3])
        self.fold_feature = nn.Linear(width + classes, fold_width)
        self.fold = shared_mlp([fold_width + 2 + 3, fold_width, 64, 3])
        g = (torch.arange(FOLD_GRID, dtype=torch.float32) + 0.5) / FOLD_GRID - 0.5
        grid = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2) * 0.1
        self.register_buffer("grid", grid)

    def forward(self, points: torch.Tensor, onehot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points (B, N, 3), onehot (B, C) -> coarse (B, COARSE_POINTS, 3), dense (B, DENSE_POINTS, 3)."""
        b, n, _ = points.shape
        f = self.first(points)  # (B, N, 128)
        g = f.max(dim=1, keepdim=True).values.expand(-1, n, -1)
        f = self.second(torch.cat([f, g], dim=-1)).max(dim=1).values  # (B, width)
        code = torch.cat([f, onehot], dim=-1)
        coarse = self.decoder(code).reshape(b, COARSE_POINTS, 3)
        k = self.grid.shape[0]
        centers = coarse.unsqueeze(2).expand(-1, -1, k, -1).reshape(b, COARSE_POINTS * k, 3)
        grid = self.grid.unsqueeze(0).expand(COARSE_POINTS, -1, -1).reshape(1, COARSE_POINTS * k, 2).expand(b, -1, -1)
        feat = torch.relu(self.fold_feature(code)).unsqueeze(1).expand(-1, COARSE_POINTS * k, -1)
        dense = centers + self.fold(torch.cat([feat, grid, centers], dim=-1))
        return coarse, dense


def chamfer_l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Symmetric Chamfer distance with unsquared nearest distances (PCN's CD-1), mean over the batch."""
    d = torch.cdist(a, b)  # (B, N, M)
    return (d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1)).mean() / 2
