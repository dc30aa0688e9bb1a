"""Per-training-image exposure: a learned colour gain and bias per image, applied to renders in training only.

Hand-held RGB-D cameras (the Kinect of 7-Scenes) adjust exposure and white balance frame by frame,
so one surface has a different colour in each image. Fitting the field to all of them at once
either averages the differences into blur or bakes them into view-dependent colour that does not
carry over to new views. With ``rendered · gain_i + bias_i`` (per channel, image i) compared to
image i, the field can store one canonical appearance and the per-image transform absorbs the
camera's changes. Maps store only the field: renders of new views are canonical.

The transforms are anchored: gains are divided by their mean over the images and the mean bias is
subtracted, so the canonical appearance is the training images' average exposure (what a new image
is closest to) rather than whatever the optimiser drifts to; unanchored, a 200-step kitchen build
lost 1.2 dB on test views (docs/MAPS.md).
"""

from __future__ import annotations

import torch


class ImageExposure(torch.nn.Module):
    """Learnable per-image, per-channel affine colour transform, initialised to the identity.

    Parameters: ``gain`` (K, 3), starting at 1, and ``bias`` (K, 3), starting at 0, for K images.
    """

    def __init__(self, images: int) -> None:
        if images < 1:
            raise ValueError(f"images={images}: expected at least one training image")
        super().__init__()
        self.gain = torch.nn.Parameter(torch.ones(images, 3))
        self.bias = torch.nn.Parameter(torch.zeros(images, 3))

    def forward(self, colours: torch.Tensor, image_index: torch.Tensor) -> torch.Tensor:
        """Colours (R, 3) rendered for rays of images ``image_index`` (R,) long -> (R, 3) as image i's camera sees them."""
        gain, bias = self.transforms()
        return colours * gain[image_index] + bias[image_index]

    def transforms(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The anchored gains (K, 3) (mean 1 per channel) and biases (K, 3) (mean 0 per channel) applied to renders."""
        return self.gain / self.gain.mean(dim=0), self.bias - self.bias.mean(dim=0)
