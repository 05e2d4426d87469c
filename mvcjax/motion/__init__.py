"""Motion: motion capture clips (BVH) and AnimatedDrawings' characters, retargeted."""

from ._bvh import BVHError as BVHError, Motion as Motion, read_bvh as read_bvh
from ._configs import (
    CharacterConfig as CharacterConfig,
    ConfigError as ConfigError,
    MotionConfig as MotionConfig,
    RetargetConfig as RetargetConfig,
    read_scene as read_scene,
)
from ._drawing import Drawing as Drawing
from ._retarget import Retargeted as Retargeted, retarget as retarget
from ._scene import Actor as Actor, PoseReport as PoseReport, Scene as Scene
