"""Grasp-image classifiers in torch: the paper's LeNet (reference) and a faster network for the CPU.

Both take float32 images (B, C, 60, 60) scaled to [0, 1] and return logits (B, 2); class 1 = grasp.
GraspNet wraps either with a softmax that keeps only P(grasp), which is what is exported to ONNX.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import nn

#: Architecture names accepted by build_network.
ARCHITECTURES = ("lenet", "fast")


class LeNet(nn.Module):
    """Caffe's LeNet as GPD uses it: conv 20@5x5, max-pool 2, conv 50@5x5, max-pool 2, ip 500 + ReLU, ip 2.

    As in Caffe's prototxt there is no non-linearity after the convolutions (~42 M multiply-adds
    per 15-channel 60x60 image).
    """

    def __init__(self, channels: int, image_size: int = 60) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(channels, 20, 5), nn.MaxPool2d(2, 2),
            nn.Conv2d(20, 50, 5), nn.MaxPool2d(2, 2),
        )
        side = ((image_size - 4) // 2 - 4) // 2
        self.classifier = nn.Sequential(nn.Flatten(), nn.Linear(50 * side * side, 500), nn.ReLU(inplace=True),
                                        nn.Linear(500, 2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.classifier(self.features(x))


def _conv_bn_relu(cin: int, cout: int, kernel: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, kernel, stride=stride, padding=kernel // 2, bias=False),
            nn.BatchNorm2d(cout), nn.ReLU(inplace=True)]


class FastNet(nn.Module):
    """A small all-3x3 CNN for CPU inference: stride-2 stem, two conv stages with max-pooling, a 64-unit
    hidden layer (~3.6 M multiply-adds per 15-channel 60x60 image, about 12x fewer than LeNet).

    Batch norm speeds training and is fused into the convolutions by onnxruntime at load time.
    """

    def __init__(self, channels: int, image_size: int = 60, width: int = 16, hidden: int = 64) -> None:
        super().__init__()
        w = width
        self.features = nn.Sequential(
            *_conv_bn_relu(channels, w, 3, stride=2),          # 30x30
            nn.MaxPool2d(2, 2),                                # 15x15
            *_conv_bn_relu(w, 2 * w, 3),
            nn.MaxPool2d(2, 2),                                # 7x7
            *_conv_bn_relu(2 * w, 2 * w, 3),
        )
        side = ((image_size + 1) // 2) // 2 // 2
        self.classifier = nn.Sequential(nn.Flatten(), nn.Dropout(0.2), nn.Linear(2 * w * side * side, hidden),
                                        nn.ReLU(inplace=True), nn.Linear(hidden, 2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.classifier(self.features(x))


class GraspProbability(nn.Module):
    """The exported graph: logits of a network -> P(grasp) (B,), the softmax of class 1."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.softmax(self.net(x), dim=1)[:, 1]


def fold_logit_affine(net: nn.Module, a: float, b: float) -> None:
    """Rescale the last linear layer so that its logit difference l1 - l0 becomes a (l1 - l0) + b: the softmax
    P(grasp) is then sigmoid(a z + b), a calibration the exported ONNX graph carries with no extra node."""
    layers = [m for m in net.modules() if isinstance(m, nn.Linear)]
    if not layers or layers[-1].out_features != 2 or layers[-1].bias is None:
        raise ValueError("the network must end in a linear layer with 2 outputs and a bias")
    last = layers[-1]
    with torch.no_grad():
        last.weight.mul_(a)
        last.bias.mul_(a)
        last.bias[1] += b


def build_network(architecture: str, channels: int, image_size: int = 60, **kwargs: Any) -> nn.Module:
    """A fresh network by name ('lenet' or 'fast'); ValueError names the known ones."""
    if channels < 1:
        raise ValueError(f"channels must be >= 1, got {channels}")
    if architecture == "lenet":
        return LeNet(channels, image_size)
    if architecture == "fast":
        return FastNet(channels, image_size, **kwargs)
    raise ValueError(f"unknown architecture {architecture!r}; known: {list(ARCHITECTURES)}")


def multiply_adds(net: nn.Module, channels: int, image_size: int = 60) -> int:
    """Multiply-adds of one forward pass on one image (convolutions and linear layers)."""
    total = 0

    def hook(module: nn.Module, inputs: tuple[torch.Tensor, ...], output: torch.Tensor) -> None:
        nonlocal total
        if isinstance(module, nn.Conv2d):
            k = module.kernel_size[0] * module.kernel_size[1] * module.in_channels // module.groups
            total += int(output.numel()) * k
        elif isinstance(module, nn.Linear):
            total += module.in_features * module.out_features

    handles = [m.register_forward_hook(hook) for m in net.modules() if isinstance(m, nn.Conv2d | nn.Linear)]
    was_training = net.training
    net.eval()
    with torch.no_grad():
        net(torch.zeros(1, channels, image_size, image_size))
    net.train(was_training)
    for h in handles:
        h.remove()
    return total


def count_parameters(net: nn.Module) -> int:
    return sum(p.numel() for p in net.parameters())
