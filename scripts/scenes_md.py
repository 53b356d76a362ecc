#!/usr/bin/env python3
"""Writes docs/scenes.md from the module docs of src/scene/*.rs (each scene
module opens with its parameter table; the scene structs' serde defaults are
held to those tables by the unit tests beside them). A unit test in
src/scene/mod.rs fails when docs/scenes.md lacks a line of those tables, so
re-run this after changing a scene module's doc:

    scripts/scenes_md.py > docs/scenes.md
"""
import os

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
ORDER = [
    ("camera", "The `camera:` block"),
    ("nerf", "`camera: {type: nerf}` (NeRF `transforms.json` cameras)"),
    ("rays", "`renderer: rays` and the shared view block"),
    ("volume", "`renderer: volume`"),
    ("volume_hash", "`field: {type: hash_mlp}` (volume)"),
    ("pathtrace", "`renderer: pathtrace`"),
    ("transport", "`renderer: transport`"),
    ("voxels", "`renderer: voxels`"),
]

HEAD = """# Scene keys

Every key a scene file may hold, per renderer, with its default, generated
from the parameter tables that open each `src/scene/<renderer>.rs` (run
`scripts/scenes_md.py > docs/scenes.md`; `cargo test` fails when this page
misses a line of those tables). Unknown keys are refused with the file and
the key. `hpjudge render SCENE --set key=value` overrides any of them.

Units: lengths and positions are world units (unitless; the volume world box
is [-1, 1]^3 unless `aabb` says otherwise); angles are degrees (`fov_y`,
`angles_deg`, `thetas`); colours, albedos and radiances are linear RGB;
densities (`s`, `sigma`, `amplitude`) are per world unit; pixel counts and
sizes are integers; seeds are u32 keys of `rand(seed, pixel, sample, dim)`.
Conventions (camera frame, pixel order, file layouts) are in the project's
scene contract; the architecture is in [ARCHITECTURE.md](ARCHITECTURE.md).
"""


def module_doc(name):
    lines = []
    with open(os.path.join(ROOT, "src", "scene", name + ".rs")) as f:
        for line in f:
            if not line.startswith("//!"):
                break
            lines.append(line[4:].rstrip("\n") if len(line) > 3 else "")
    return "\n".join(lines).strip() + "\n"


def main():
    out = [HEAD]
    for name, title in ORDER:
        out.append(f"## {title}\n\nFrom `src/scene/{name}.rs`:\n\n{module_doc(name)}")
    print("\n".join(out), end="")


if __name__ == "__main__":
    main()
