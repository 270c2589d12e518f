"""The one unit factor between the domains: :mod:`cadcam` speaks millimetres, :mod:`robotprog` and
:mod:`vision` speak metres. The part crosses at named functions (``robotprog.frames.setup_sheet_to_cell``,
``factory.cam.vise_jaws``, the views of :mod:`factory.views`); each uses this factor, so a reader finds
every crossing by grepping one name."""

#: Millimetres per metre: a CAM length [mm] / MM_PER_M is a cell length [m].
MM_PER_M = 1000.0
