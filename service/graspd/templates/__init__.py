"""Grasp templates from demonstrations, improved by failures (Herzog et al. 2012): graspd's second detector.

Library API (what the service wires into endpoints; every error is a TemplateError or CloudError, both
graspd.core.errors.FieldError (a ValueError) whose .field names the offending field: answer them with 4xx):

    from graspd.templates import TemplateLibrary, TemplateDetector, TemplateParams, TemplateError

    library = TemplateLibrary(url)                 # SQLAlchemy URL; default sqlite:///graspd-templates.db.
                                                   # Created and migrated on open; safe for many processes.
                                                   # Optional hand=HandGeometry (fixed per library; the
                                                   # template size is derived from it).
    detector = TemplateDetector(library)           # one per process; thread-safe for detect()

    POST /demonstrations  -> entry_id = library.add_demonstration(cloud: ViewpointCloud,
                                          hand_pose: 4x4 (rotation columns [approach, binormal, axis],
                                          translation = hand base centre, cloud frame), label=None,
                                          workspace=None)          # -> int
    POST /feedback        -> fb = library.add_feedback(grasp_id: str, success: bool, cloud=None, image=None)
                                          # -> Feedback; fb.to_dict() is JSON-ready.  Unknown ids raise
                                          # UnknownGrasp(field "grasp_id") -> 404; malformed TemplateError -> 422.
                          library.add_outcome(grasp_id, success, pose, width, image)  # a GPD grasp's outcome
    GET /library          -> library.summary()      # JSON-ready dict: counts, hand, template, entries[]
    POST /detect method="templates"
                          -> det = detector.detect(cloud, max_grasps=100, workspace=None)
                             det.to_dict()          # {"method": "templates", "grasps": [GRASP + "id",
                                                    #  "template_entry", "mismatch"], "timings": {...},
                                                    #  "num_candidates", "num_points", "num_entries",
                                                    #  "detection_id"}
                             det.grasps is a graspd.core.grasp.GraspSet (its grasp convention, best first,
                             score = 1 / (1 + m) in (0, 1]); det.grasp_ids[k] is the id for feedback.
                             The library's hand is used (a per-request hand override does not apply).
                             An empty library answers no grasps (num_entries = 0).

A fleet shares one library through PostgreSQL: TemplateLibrary("postgresql+psycopg://user@host/db")
(needs the psycopg package); SQLite files work for many processes on one machine (WAL, queued writers).
Grasp ids are "<detection id>.<k>" and stay valid across restarts and processes.

For fine-tuning GPD later: library.iter_outcomes(with_images_only=True) yields every outcome with its
grasp pose, template and GPD grasp image (uint8 (15, 60, 60) by default).

Shell: `graspd templates {demonstrate,detect,feedback,library}` (graspd.cli.templates.register; add
"graspd.cli.templates" to graspd.cli.main.SUBCOMMAND_MODULES).  Simulation experiments (scripted
demonstrations, the paper's generalisation and improvement-over-time runs) live in graspd_lab.sim.experiments
(python bench/templates.py experiment {a,b,retry,pool}).

Modules: geometry (templates, table, hull axes, occlusion), matching (eq. 1, eq. 2), library (entries,
failure sets, detections; its database is graspd.store.database, its outcomes graspd.store.outcomes), demonstration
(template of a demonstrated grasp; grasp images), collision (the open hand against the scene; closing
widths), detector, cli.  Synthetic table scenes are graspd_lab.world (meshes, objects, render).
"""

from graspd.store.outcomes import Feedback
from graspd.templates.detector import TemplateDetection, TemplateDetector, TemplateParams
from graspd.templates.geometry import REGION_NAMES, TemplateError, TemplateGeometry
from graspd.templates.library import DEFAULT_URL, TemplateLibrary, UnknownGrasp

__all__ = [
    "DEFAULT_URL",
    "REGION_NAMES",
    "Feedback",
    "TemplateDetection",
    "TemplateDetector",
    "TemplateError",
    "TemplateGeometry",
    "TemplateLibrary",
    "TemplateParams",
    "UnknownGrasp",
]
