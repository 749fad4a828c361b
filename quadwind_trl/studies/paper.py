"""The paper's published figures, to print beside ours (never used to compute anything)."""
from __future__ import annotations

# Table 4: horizontal tracking by mean wind speed (RMSE in m; shares in %)
HORIZONTAL_BY_WIND = {
    4.0: {"pd": 0.650, "blind": 0.562, "aware": 0.508, "improvement": 21.8, "perception_share": 38.0},
    6.0: {"pd": 0.745, "blind": 0.663, "aware": 0.531, "improvement": 28.7, "perception_share": 61.7},
    8.0: {"pd": 0.962, "blind": 0.836, "aware": 0.594, "improvement": 38.3, "perception_share": 65.9},
    10.0: {"pd": 1.477, "blind": 1.182, "aware": 0.758, "improvement": 48.7, "perception_share": 59.0},
    12.0: {"pd": 2.743, "blind": 1.679, "aware": 1.031, "improvement": 62.4, "perception_share": 37.8},
    "all": {"pd": 1.315, "blind": 0.985, "aware": 0.684, "improvement": 48.0, "perception_share": 47.6},
}
# Table 5: horizontal tracking by trajectory
HORIZONTAL_BY_TRAJECTORY = {
    "cloverleaf_h": {"pd": 0.947, "aware": 0.635, "improvement": 33.0},
    "racetrack_h": {"pd": 1.232, "aware": 0.732, "improvement": 40.6},
    "figure8_h": {"pd": 1.079, "aware": 0.592, "improvement": 45.1},
    "loiter_circle_h": {"pd": 1.327, "aware": 0.646, "improvement": 51.3},
    "lawnmower_h": {"pd": 1.992, "aware": 0.817, "improvement": 59.0},
}
# Table 6: vertical regime, horizontal (xy) tracking by mean wind speed
VERTICAL_BY_WIND = {
    3.0: {"pd": 0.576, "blind": 0.398, "aware": 0.409, "improvement": 28.9, "perception_share": -7.0},
    5.0: {"pd": 0.609, "blind": 0.447, "aware": 0.422, "improvement": 30.6, "perception_share": 13.4},
    7.0: {"pd": 0.734, "blind": 0.551, "aware": 0.439, "improvement": 40.2, "perception_share": 38.0},
    9.0: {"pd": 0.986, "blind": 0.728, "aware": 0.487, "improvement": 50.6, "perception_share": 48.3},
    "all": {"pd": 0.726, "blind": 0.531, "aware": 0.440, "improvement": 39.5, "perception_share": 31.9},
}
# Table 3: tracking statistics (mean +- std over matched pairs)
TRACKING_STATS = {
    "horizontal": {"n": 225, "pd": (1.32, 1.22), "aware": (0.68, 0.23), "improvement": 48.0, "ci": (43.3, 52.4), "wins": 225},
    "vertical_xy": {"n": 144, "pd": (0.73, 0.19), "aware": (0.44, 0.07), "improvement": 39.5, "ci": (37.2, 41.6), "wins": 144},
    "vertical_z": {"n": 144, "pd": (0.49, 0.21), "aware": (0.37, 0.25), "improvement": 25.1, "ci": (22.0, 28.6), "wins": 141},
}
# Out-of-distribution (text and Fig. 11)
OOD = {"pd_mean": 5.19, "aware_mean": 1.30, "improvement": 74.9, "wins": 90, "n": 90, "pd_worst": 47.0, "aware_worst": 3.8,
       "by_wind_improvement": {13.0: 68.7, 15.0: 78.5}}
# Tables 1-3: estimation
ESTIMATION_HORIZONTAL = {"per_window_vector_rmse": 1.05, "component_mean_rmse": 0.74, "per_flight_vector_rmse": 0.40,
                         "direction_mae_deg": 3.2, "corr_n": 0.996, "corr_e": 0.996}
ESTIMATION_HORIZONTAL_BY_TRAJECTORY = {
    "loiter_circle_h": (0.34, 3.0), "figure8_h": (0.41, 3.1), "cloverleaf_h": (0.43, 3.3),
    "lawnmower_h": (0.46, 3.3), "racetrack_h": (0.51, 3.2),
}  # (per-flight vector RMSE m/s, direction MAE deg)
ESTIMATION_VERTICAL = {"per_window_vector_rmse": 1.56, "component_mean_rmse": 1.11, "direction_mae_deg": 4.9,
                       "corr_n": 0.991, "corr_e": 0.991, "vector_skill": 0.861, "speed_skill": 0.899,
                       "constant_reference_rmse": 11.26, "altitude_slope_pred": 6.9e-3, "altitude_slope_true": 7.2e-3}
