"""
Write docs/scene_reference.md from softseq_ros/scene/reference.py.

    python tools/scene_reference.py
"""

from pathlib import Path
import sys

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from softseq_ros.scene.reference import reference_text  # noqa: E402

if __name__ == '__main__':
    out = REPO / 'docs' / 'scene_reference.md'
    out.write_text(reference_text(), encoding='utf-8')
    print(f'wrote {out}')
