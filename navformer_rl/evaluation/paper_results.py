"""The paper's published numbers (Tables I-IV), for reference beside ours in reports.

They were measured in Gazebo with the authors' worlds and trained models; ours come from the pybullet
mazes of this package, so the two are not directly comparable. Values: SR as a fraction in [0, 1],
SPL and CR as published.
"""

from __future__ import annotations

from navformer_rl.tasks import ABLATIONS

PAPER_SOURCE = "Wang, Tan, Nejat, NavFormer (RA-L 2024), Gazebo simulator"

TABLE1_METHODS: tuple[str, ...] = ("VRW", "DSAC", "MA-TDN", "DT", "FCA", "NavFormer")
"""Column order of Table I."""

# (size m, robots) -> method -> (SR, SPL, CR); transcribed from Table I.
_TABLE1_ROWS: dict[tuple[float, int], tuple[tuple[float, float, float], ...]] = {
    (7.5, 2): ((39.17, 0.287, 0.691), (53.33, 0.377, 0.316), (61.67, 0.315, 0.314),
               (57.50, 0.419, 0.405), (94.17, 0.653, 0.044), (80.83, 0.562, 0.228)),
    (7.5, 4): ((33.33, 0.220, 0.694), (47.08, 0.353, 0.395), (46.67, 0.248, 0.542),
               (47.92, 0.395, 0.529), (80.83, 0.598, 0.142), (66.25, 0.465, 0.325)),
    (7.5, 6): ((32.78, 0.187, 0.711), (42.78, 0.337, 0.493), (43.06, 0.234, 0.559),
               (40.28, 0.332, 0.608), (76.11, 0.580, 0.101), (54.44, 0.435, 0.430)),
    (12.5, 2): ((16.67, 0.100, 0.678), (24.17, 0.179, 0.324), (30.00, 0.159, 0.387),
                (39.17, 0.258, 0.372), (85.00, 0.599, 0.070), (53.33, 0.374, 0.251)),
    (12.5, 4): ((15.83, 0.104, 0.680), (19.17, 0.133, 0.460), (23.33, 0.137, 0.394),
                (26.25, 0.201, 0.430), (73.33, 0.482, 0.096), (48.89, 0.378, 0.223)),
    (12.5, 6): ((13.61, 0.101, 0.716), (23.89, 0.180, 0.550), (23.06, 0.118, 0.488),
                (31.94, 0.231, 0.530), (60.28, 0.454, 0.071), (48.75, 0.359, 0.355)),
    (17.5, 2): ((5.83, 0.053, 0.666), (10.00, 0.084, 0.371), (20.83, 0.117, 0.342),
                (34.17, 0.222, 0.352), (57.50, 0.395, 0.068), (44.17, 0.316, 0.279)),
    (17.5, 4): ((5.00, 0.032, 0.622), (10.00, 0.085, 0.472), (13.75, 0.078, 0.494),
                (22.08, 0.151, 0.449), (47.50, 0.331, 0.100), (38.33, 0.279, 0.204)),
    (17.5, 6): ((5.83, 0.032, 0.585), (10.56, 0.092, 0.538), (16.39, 0.098, 0.554),
                (22.50, 0.169, 0.546), (40.83, 0.296, 0.081), (35.56, 0.272, 0.350)),
}  # fmt: skip

TABLE1: dict[tuple[float, int], dict[str, tuple[float, float, float]]] = {
    setup: {m: (sr / 100.0, spl, cr) for m, (sr, spl, cr) in zip(TABLE1_METHODS, row)}
    for setup, row in _TABLE1_ROWS.items()
}
"""Table I: ``TABLE1[(size, robots)][method] = (SR, SPL, CR)``, SR as a fraction."""

TABLE2: dict[str, tuple[float, float, float]] = {
    "VRW": (0.0889, 0.062, 0.612), "DSAC": (0.1111, 0.081, 0.620), "MA-TDN": (0.1778, 0.122, 0.590),
    "DT": (0.2222, 0.148, 0.510), "FCA": (0.8222, 0.612, 0.092), "NavFormer": (0.3667, 0.269, 0.412),
}  # fmt: skip
"""Table II (unseen photorealistic worlds: bookstore, cafe, house; 3 Jackals, 30 trials each), one row per
method over all three kinds; ours: the ``table2`` protocol's pooled ``all`` row."""

TABLE3: dict[str, dict[str, tuple[float, float, float]]] = {
    "seen": {
        "VRW": (0.1583, 0.104, 0.680), "DSAC": (0.1917, 0.133, 0.460), "MA-TDN": (0.2333, 0.137, 0.394),
        "DT": (0.2625, 0.201, 0.430), "FCA": (0.7333, 0.482, 0.096), "NavFormer": (0.4889, 0.378, 0.223),
    },
    "unseen": {
        "VRW": (0.1333, 0.101, 0.591), "DSAC": (0.1667, 0.131, 0.606), "MA-TDN": (0.2167, 0.157, 0.552),
        "DT": (0.2167, 0.190, 0.501), "FCA": (0.7500, 0.442, 0.086), "NavFormer": (0.4167, 0.322, 0.301),
    },
}  # fmt: skip
"""Table III (12.5 m, 4 robots): seen (Jackal) vs unseen (TurtleBot3) dynamic obstacles."""

TABLE4: dict[str, tuple[float, float, float]] = {
    "NavFormer": (0.4889, 0.378, 0.223),
    "NavFormer w/o SSL": (0.3958, 0.272, 0.376),
    "NavFormer w/o THSC": (0.3208, 0.261, 0.500),
    "NavFormer w/o tau^e": (0.1208, 0.109, 0.280),
    "NavFormer w/o tau^ca": (0.4083, 0.256, 0.237),
    "NavFormer w/o f_s": (0.4125, 0.289, 0.230),
    "NavFormer w/o f_g": (0.3833, 0.273, 0.396),
    "NavFormer w ResNet18": (0.0792, 0.080, 0.765),
}
"""Table IV, the ablation study (12.5 m, 4 robots)."""

METHOD_TO_PAPER_COLUMN: dict[str, str] = {
    "vrw": "VRW", "dsac": "DSAC", "matdn": "MA-TDN", "dt": "DT", "fca": "FCA", "navformer": "NavFormer"
}  # fmt: skip
"""Our method names -> the paper's column names."""

ABLATION_TO_TABLE4: dict[str, str] = {name: a.paper_row for name, a in ABLATIONS.items() if a.paper_row}
"""The training recipe's ablation names -> their Table IV rows (:data:`navformer_rl.tasks.ABLATIONS`)."""
TABLE4_SETUP: tuple[float, int] = (12.5, 4)
"""Table IV's setup: 60 trials in 12.5 m mazes with 4 robots (paper §VII.D)."""
