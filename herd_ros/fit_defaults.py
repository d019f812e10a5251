"""The fit's defaults and candidate sets: constants only.

:mod:`herd_ros.estimation.model_selection` searches over them and
:mod:`herd_ros.model.rbf_field` builds its grids with them; they live here, apart from the
numerics, so that ``herd-ros fit --help`` shows them without importing numpy, scipy or numba.
"""

#: Up to this many agents the interactions are the paper's pairwise law; more get the
#: shared distance profile.
PAIRWISE_MAX_AGENTS = 6
#: Ridge values tried (0 = plain least squares).
RIDGES = (0.0, 1e-3, 1e-2, 1e-1)
#: Field cells tried (each arranged to the region's aspect ratio), at most one cell per
#: :data:`SAMPLES_PER_FIELD_CELL` samples of an agent.
FIELD_CELLS = (4, 16, 64)
SAMPLES_PER_FIELD_CELL = 40
#: Contiguous blocks per run.
FOLDS = 10
#: The structures (model terms) the selection tries; `fit --terms full` is the last one.
TERMS = ('damping', 'damping+field', 'damping+interactions', 'damping+interactions+field')
#: Velocity memories κ tried on the structure chosen with κ = 1 (:mod:`velocity_memory`).
MEMORIES = (0.6, 0.35, 0.2)
#: Default number of samples of an agent that must fall in a cell to keep its centre.
DEFAULT_MIN_VISITS = 10
