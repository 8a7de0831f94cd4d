"""The BVH files in tests/fixtures, both synthetic (random angles, made-up offsets): ``mixed_channels.bvh`` mixes
channel orders and sets per joint; ``bandai_namco_rig.bvh`` has the Bandai-Namco joint names and layout, with a
moving, turning ``joint_Root`` above ``Hips``."""

from __future__ import annotations

from pathlib import Path

FIXTURES = Path(__file__).resolve().parents[2] / "fixtures"
MIXED = FIXTURES / "mixed_channels.bvh"
BANDAI = FIXTURES / "bandai_namco_rig.bvh"
