"""The contract's other files: observations.json, verify.json and batch.json (result.json's is :mod:`.models`)."""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import Field, StrictBool, StrictInt, StrictStr, model_validator

from .fields import Count, ImageSize, Matrix4, Number, NumberRows, Rigid, Sigma, Vec2, Vec3, damaged
from .models import Mapping, Open, XName


# ------------------------------------------------------------------------------------ observations.json
class ObservedView(Open):
    """One used view of observations.json: its corners and their fits under the final solution."""

    corner_ids: list[Count]
    image_points_px: list[Vec2]
    sharpness: Optional[Number] = None
    image: Optional[StrictStr] = None
    T_cam_board_pnp: Optional[Matrix4] = None
    T_cam_board_chain: Optional[Matrix4] = None
    residual_pnp_px: Optional[NumberRows] = None
    residual_chain_px: Optional[NumberRows] = None
    T_base_end_reported: Optional[Matrix4] = None


class FailedView(Open):
    reason: Optional[StrictStr] = None
    image: Optional[StrictStr] = None


class Observations(Open):
    """observations.json: per view, the detected corners and their residuals (the report's figures)."""

    handeye_observations: StrictInt = Field(ge=1, description="observations.json format version")
    mode: Optional[StrictStr] = None
    target: Optional[Mapping] = None
    object_points_m: list[Vec3] = Field(default_factory=list)
    image_size: Optional[ImageSize] = None
    views: dict[str, ObservedView] = Field(default_factory=dict)
    failed_views: dict[str, FailedView] = Field(default_factory=dict)
    run_id: Optional[StrictStr] = None


# ------------------------------------------------------------------------------------------ verify.json
class VerifyTest(Open):
    kind: Optional[StrictStr] = None
    statistic: Optional[Number] = None
    dof: Optional[Number] = None
    p_value: Optional[Number] = None
    alpha: Optional[Number] = None


class Verify(Open):
    """verify.json: an installed calibration tested against a short new session (``handeye verify``)."""

    handeye_verify: StrictInt = Field(ge=1, description="verify.json format version")
    verdict: Literal["still valid", "drifted"]
    headline: StrictStr
    drifted: StrictBool
    mode: Literal["eye_in_hand", "eye_to_hand"]
    frame: XName
    test: VerifyTest
    change: Optional[Mapping] = None
    installed: Optional[dict[str, Rigid]] = None
    posterior: Optional[Mapping] = None
    board: Optional[Mapping] = None
    robot: Optional[Mapping] = None
    intrinsics: Optional[Mapping] = None
    what_moved: list[StrictStr] = Field(default_factory=list)
    views: Optional[Mapping] = None
    n_views: Optional[Count] = None
    sigma_px: Optional[Sigma] = None
    session: Optional[Mapping] = None
    against: Optional[StrictStr] = None
    view_outcomes: Optional[list[Mapping]] = None
    provenance: Optional[Mapping] = None

    @model_validator(mode="after")
    def _agree(self):
        if self.drifted != (self.verdict == "drifted"):
            raise damaged(
                f"is {self.drifted} with verdict {self.verdict!r}", "drifted == (verdict == 'drifted')", "drifted"
            )
        return self


# ------------------------------------------------------------------------------------------- batch.json
class BatchRecord(Open):
    """batch.json: what ``handeye batch`` recorded of one session's run (beside its outputs)."""

    session: StrictStr
    install: Optional[StrictStr] = None
    name: Optional[StrictStr] = None
    time_utc: Optional[StrictStr] = None
    time_source: Optional[StrictStr] = None
    key: Mapping
    outcome: Literal["done", "error", "timeout", "crashed", "lost"]
    status: Optional[Literal["ok", "failed"]] = None
    verdict: Optional[Literal["PASS", "WARN", "FAIL", "REFUSED", "ERROR", "VALID", "DRIFTED"]] = None
    reason: Optional[StrictStr] = None
    exit_code: Optional[StrictInt] = None
    worker: Optional[StrictStr] = None
    started_utc: Optional[StrictStr] = None
    finished_utc: Optional[StrictStr] = None
    seconds: Optional[Sigma] = None
    exported: Optional[list[StrictStr]] = None
    export_error: Optional[StrictStr] = None
    peak_rss_mb: Optional[Sigma] = None
