"""Reprojection factors (pure numpy residuals + thin GTSAM wrappers)."""
