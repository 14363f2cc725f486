"""Pictures of the scenarios: one frame's left image beside its colour-mapped true disparity.

``python -m common.scenarios.preview docs/scenarios`` writes one PNG per scenario (the frames
chosen to show what each scenario is about); invalid disparity (sky, occluded in the right view,
outside it) is black.
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from common.scenarios.catalogue import SCENARIOS, build
from common.scenarios.render import Renderer, Rig
from common.scenarios.simulate import FRAME_RATE_HZ

#: frame shown per scenario: the crossing while walkers cross, the sign and barrier ahead, ...
FRAMES = {"urban": 30, "crossing": 55, "overtake": 40, "hanging": 15, "slope": 45, "lowtexture": 30}
MAX_DISPARITY = 64.0


def colour_disparity(disparity: npt.NDArray[np.float32]) -> npt.NDArray[np.uint8]:
    """Turbo colour map over 0..MAX_DISPARITY px, invalid black (BGR)."""
    scaled = np.clip(np.nan_to_num(disparity, nan=0.0) / MAX_DISPARITY * 255, 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    out[~np.isfinite(disparity)] = 0
    return out


def preview(name: str, out: Path, seed: int = 1, frame: int | None = None) -> Path:
    """Render one frame of a scenario and write the side-by-side PNG."""
    k = FRAMES.get(name, 30) if frame is None else frame
    renderer = Renderer(build(name, seed), Rig())
    rendered = renderer.render(k / FRAME_RATE_HZ, np.random.default_rng([seed, k]))
    left = cv2.cvtColor(rendered.left, cv2.COLOR_RGB2BGR)
    picture = np.hstack([left, colour_disparity(rendered.disparity)])
    label = f"{name}  seed {seed}  frame {k}"
    cv2.putText(picture, label, (10, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 255), 2, cv2.LINE_AA)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), picture)
    return out


def main(argv: list[str]) -> int:
    folder = Path(argv[0]) if argv else Path("docs/scenarios")
    for name in SCENARIOS:
        print(preview(name, folder / f"{name}.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
