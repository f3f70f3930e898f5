"""Every stated maximum of pushplan's inputs, in one place (SI units, degrees where
named ``_DEG``).  Validation (:mod:`pushplan.config.validate`, :mod:`pushplan.cli.args`)
refuses a value outside them with one line naming the key and the bound, before any
work; so every loop a user can make long has a work budget, and every number a
magnitude a float holds.  Imports nothing (``pushplan --help`` reads it)."""

MAX_STEPS = 100_000
"""Load steps of a run after ``repeat`` (scenario ``[[load]]``, ``--commands`` file)."""
MAX_ELEMENTS = 1_000_000
"""Most hex8 elements of a block: far beyond what fits in memory (dense flexibility matrix)."""
MAX_ELEMENTS_PER_AXIS = 100_000
MAX_COUNT = 2**31 - 1
"""Any other count without a stated maximum of its own (a C int)."""

MIN_TOLERANCE = 1e-15
"""Smallest relative tolerance (``newton_tol``, ``local_tol``): a relative residual
below double-precision rounding (2.2e-16) cannot be reached, so a smaller one only
turns the iteration limit into the run time."""
MAX_NEWTON_ITER = 1_000
"""``solver.newton_max_iter`` (default 100)."""
MAX_LOCAL_ITER = 100_000
"""``solver.local_max_iter`` (defaults 100 Newton, 20000 Uzawa)."""
MAX_ACCELERATION = 50
"""``solver.acceleration`` (default 4): Anderson differences kept in the Newton loop."""

MAX_PLAN_STEPS = 500
"""``[plan] steps``: commands of a plan (the NLP grows with them)."""
MAX_ROLLOUTS = 100
"""``[plan] max_rollouts`` (default 6): FE rollouts of the planner's outer loop."""
MAX_ROBUST_ITERATIONS = 100
"""``[plan] robust.max_iterations`` (default 8): sigma-point evaluations of the robust refinement."""
MAX_MONTE_CARLO = 100_000
"""``[plan] robust.monte_carlo`` (default 50): truths of the robust plan's Monte Carlo check."""
MAX_EPISODES = 10
"""``[plan] episodes`` (default 3): grasp, push and release cycles of ``closed-loop`` to a rest target."""
MAX_SUGGEST = 36
"""``identify --suggest N``: one push per 10 degrees."""
MAX_LEVELS = 8
"""``convergence --levels``: meshes of a study."""
MAX_RATIO = 10.0
"""``convergence --ratio``, ``plan --verification-ratio``: refinement ratio between meshes."""
MAX_OBSERVATION_ROWS = 10_000
"""Rows of an observation file (each one is a step to re-simulate in every rollout)."""
MAX_WORKERS = 1024
"""Sweep / convergence pool size."""

MIN_POSE_NOISE, MAX_POSE_NOISE = 1e-12, 1.0
"""``--pose-noise``, m: 1 pm (far below any sensor; 1/sigma^2 stays far from overflow) to 1 m."""
MIN_YAW_NOISE_DEG = 1e-9
MAX_FORCE_NOISE = 1e6
"""``--force-noise``, N."""
MAX_FORCE_NOISE_REL = 10.0

MAX_CONTROL_PERIOD = 10.0
"""``[mujoco] control_period`` and ``settle_time``, s of MuJoCo time per command."""
MAX_FLEX_POINTS = 16
"""``[mujoco] flex_points``, per direction (16^3 = 4096 flex vertices)."""
MAX_GRIPPER_STIFFNESS = 1e15
"""N/m (N m/rad for the yaw spring): stiffer than any solid contact, inf is the rigid drive."""

MAX_LENGTH = 100.0
"""m: any length of a plan (target, step, tolerance); a block is centimetres to metres."""
MIN_PLAN_STEP = 1e-9
"""m: the smallest ``[plan] max_step`` (1 nm): below it a push is below the solver's
tolerance and the calibration measures noise."""
MIN_TOLERANCE_LENGTH = 1e-12
"""m: the smallest ``[plan] tolerance``."""
MAX_EFFORT_WEIGHT = 1e6
"""``[plan] effort_weight`` (default a small fraction): larger only ignores the target."""
MAX_MUJOCO_STEPS = 10_000_000
"""MuJoCo steps of one co-simulation or comparison model (commands x (control period +
settle time) / timestep): about a minute of a small scene."""
