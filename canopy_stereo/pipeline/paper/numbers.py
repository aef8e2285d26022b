"""The numbers Ni & Burks print (the only constants of the paper run), and what the run covers."""
from __future__ import annotations

#: Table 1: axis -> (mean absolute error, standard deviation), mm.
PAPER_TABLE1 = {"X": (0.42, 0.35), "Y": (0.36, 0.31), "Z": (2.78, 1.74)}

#: Columns of Tables 2-4 (the paper's), in order.
PAPER_COLUMNS = ("t1_s", "num1", "t2_s", "num2", "t_s", "propagation_s", "resample_s", "num",
                 "distribution_pct")

#: Tables 2-4: table -> method -> the paper's row (None where it prints "/").
PAPER_FEATURE_TABLES = {
    "aloe": {
        "harris-affine": (0.27, 279, 0.27, 349, 0.03, None, None, 31, 0.42),
        "hessian-affine": (0.17, 344, 0.16, 298, 0.03, None, None, 36, 0.58),
        "sift": (1.25, 3284, 1.28, 3384, 0.23, None, None, 609, 9.54),
        "asift": (15.04, 20281, 16.70, 25704, 1.56, None, None, 2377, 18.98),
        "surf": (0.23, 401, 0.24, 447, 0.09, None, None, 100, 2.00),
        "qdmatch": (0.15, 5705, 0.07, 4823, 0.06, 2.76, 3.40, 1624, 31.08),
    },
    "banyan": {
        "harris-affine": (0.36, 1137, 0.35, 1028, 0.08, None, None, 19, 0.31),
        "hessian-affine": (0.28, 1367, 0.28, 1379, 0.09, None, None, 34, 0.54),
        "sift": (1.17, 2307, 1.34, 3467, 0.17, None, None, 148, 2.35),
        "asift": (18.38, 3118, 18.35, 31358, 2.41, None, None, 663, 6.73),
        "surf": (0.39, 808, 0.38, 752, 0.16, None, None, 64, 1.25),
        "qdmatch": (0.10, 3772, 0.08, 4812, 0.06, 3.32, 3.82, 1423, 27.25),
    },
    "croton": {
        "harris-affine": (0.36, 989, 0.36, 1006, 0.06, None, None, 110, 1.73),
        "hessian-affine": (0.29, 1131, 0.32, 1306, 0.07, None, None, 155, 2.63),
        "sift": (1.12, 2092, 1.11, 2012, 0.13, None, None, 451, 6.88),
        "asift": (16.63, 26960, 17.03, 27972, 2.06, None, None, 4386, 22.88),
        "surf": (0.49, 1039, 0.51, 1055, 0.22, None, None, 326, 6.27),
        "qdmatch": (0.11, 2418, 0.05, 2500, 0.02, 2.03, 3.30, 1546, 28.08),
    },
}

#: The two marked croton leaves: id -> ruler (width, length) and the paper's
#: reconstruction (width, length), mm (Figures 21 and 22).
PAPER_LEAVES = {1: {"ruler": (97.0, 160.0), "paper": (94.46, 156.24)},
                2: {"ruler": (86.0, 145.0), "paper": (87.04, 144.00)}}

#: Feature methods of the full and the quick run.
FULL_METHODS = ("harris-affine", "hessian-affine", "sift", "asift", "surf", "orb", "akaze",
                "qdmatch")
QUICK_METHODS = ("sift", "asift", "qdmatch")

#: Placements of the world-rig calibration: full = the paper's 45, quick = 9 of them
#: (three per line, spread along each line).
QUICK_PLACEMENTS = 9

#: Table number, paper table and shipped pair of the feature study.
FEATURE_SCENES = (
    ("2", "aloe", "plants", "Middlebury 2014 Plants (real, bundled in bags/plants.mcap)"),
    ("3", "banyan", "citrus_branch", "synthetic citrus branch (canopy_stereo.sim, small leaves)"),
    ("4", "croton", "croton", "synthetic croton (canopy_stereo.sim, the paper's rig)"),
)
