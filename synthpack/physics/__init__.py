"""Physics: pouring grains into a virtual tube, batch by batch, with a rigid-body engine (paper 3.3).

Modules, one job each, in the order a pour runs them:

=====================  ==================================================================================
``config``             `PourConfig`: the pour's settings (count, batch, tube, scale, engine, target); sizes its tube
``pouring``            `pour(library, config, seed)`: check -> plan -> engine, batch by batch -> checks -> `Placements`
``plan``               the seeded pour plan: which grains, at what scale, orientation and drop height
``container``          `Tube`: the container, sized for the pour; an interior crop's tube and box
``compaction``         packing to a target solid fraction, steered by the bulk after each locked batch
``shells``             a target coordination: which grains of a spaced pour collide bare, the others' shells
``scene``              `Scene`: the grains, tube, material, settle criteria and options every engine pours
``driver``             the one batch loop (spawn, settle, lock, retire, snapshot) over an engine's hooks
``engine``             the `Engine` base class every engine subclasses
``registry``           the engines by name
``pybullet_engine``    the default engine (pybullet), with ``_bullet`` (its client)
``blender_engine``     Blender's engine, run in its own interpreter by ``blender_script``
``hulls``, ``burial``  collision hulls, and which buried grains the driver retires
``checks``             containment, overlap and settling checks of a finished pour
``placements``         `Placements`: the poses of a pour, saved and read as JSON
=====================  ==================================================================================
"""

from .compaction import PackingController
from .config import PourConfig
from .container import Tube
from .scene import Material, SettleCriteria
from .placements import Placements
from .pouring import CONTAINMENT_ATTEMPTS, LockedGrains, check_pour_size, pour
from .checks import PourChecks
from .registry import ENGINES, get_engine

__all__ = [
    "CONTAINMENT_ATTEMPTS", "ENGINES", "LockedGrains", "Material", "PackingController", "Placements", "PourChecks",
    "PourConfig", "SettleCriteria", "Tube", "check_pour_size", "get_engine", "pour",
]
