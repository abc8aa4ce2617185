"""The controller's parameters: one frozen model, every field a documented knob."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator


class ControllerConfig(BaseModel):
    """Parameters of :class:`~lidarfuzz.suts.controller.avoidance.ObstacleAvoidance` and its
    :class:`~lidarfuzz.suts.controller.vfh.VFH` (defaults for a car at urban speeds)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    # timing
    period: float = Field(default=0.1, gt=0.0, description="seconds between frames when the log has no timestamps")
    max_dt: float = Field(default=0.5, gt=0.0, description="a longer gap between frames counts as this many seconds")
    # ground estimate
    sensor_height: float = Field(default=1.73, gt=0.0, description="sensor above the road (m): the fallback ground")
    ground_threshold: float = Field(default=0.15, gt=0.0, description="distance to the plane still ground (m)")
    ransac_iterations: int = Field(default=40, ge=1)
    ransac_sample: int = Field(default=2000, ge=3, description="points the RANSAC hypotheses are scored on")
    max_tilt_deg: float = Field(default=12.0, ge=0.0, le=90.0, description="steeper planes are not the road")
    min_ground_points: int = Field(default=50, ge=3, description="fewer inliers: the plane is not trusted")
    seed: int = Field(default=0, description="seed of RANSAC's generator (the controller is deterministic)")
    min_points: int = Field(default=20, ge=3, description="a frame with fewer points is blind")
    # obstacle classification by elevation
    min_height: float = Field(default=0.3, gt=0.0, description="lowest height above ground of an obstacle point (m)")
    max_height: float = Field(default=2.5, gt=0.0, description="higher points (branches, bridges) pass over the car")
    step_height: float = Field(default=0.3, gt=0.0,
                               description="a cell whose points rise this much above its lowest one holds an "
                                           "obstacle even where the plane is off (kerb-high steps and more)")
    cell: float = Field(default=0.5, gt=0.0, description="cell of the local obstacle grid (m)")
    min_cell_points: int = Field(default=3, ge=1, description="fewer obstacle points in a cell: noise")
    full_cell_points: int = Field(default=10, ge=1, description="obstacle points that make a cell certain: its "
                                                                   "VFH weight is min(1, points / this)²")
    min_range: float = Field(default=1.0, ge=0.0, description="nearer points are the car itself (m)")
    max_range: float = Field(default=25.0, gt=0.0, description="farther obstacles are ignored (m)")
    # vector field histogram
    field_of_view_deg: float = Field(default=180.0, gt=0.0, le=360.0, description="directions considered, centred")
    sector_deg: float = Field(default=5.0, gt=0.0, le=45.0, description="width of one histogram sector")
    window_radius: float = Field(default=12.0, gt=0.0, description="the VFH's active window: obstacle cells farther "
                                                                 "away do not count, nearer ones weigh 1 − d / this")
    robot_radius: float = Field(default=1.0, gt=0.0, description="half the car's width (m)")
    safety_distance: float = Field(default=0.5, ge=0.0, description="kept between the car and obstacles (m)")
    smoothing: int = Field(default=2, ge=0, description="sectors on each side averaged into one")
    threshold_high: float = Field(default=3.0, gt=0.0, description="density above which a sector becomes blocked")
    threshold_low: float = Field(default=1.5, ge=0.0, description="density below which a blocked sector is free")
    wide_valley: int = Field(default=4, ge=1, description="a valley of this many sectors or more is wide; the car "
                                                          "keeps half of it off a wide valley's border")
    goal_direction_deg: float = Field(default=0.0, description="where the car wants to go, left positive (a frame's "
                                                               "metadata 'goal_direction' in radians overrides it)")
    # steering
    steering_gain: float = Field(default=1.0, gt=0.0, description="steering per radian of chosen direction")
    max_steering: float = Field(default=0.5, gt=0.0, le=1.5, description="steering limit (rad)")
    max_steering_rate: float = Field(default=0.6, gt=0.0, description="steering change per second (rad/s)")
    # speed
    cruise_speed: float = Field(default=8.0, gt=0.0, description="speed on a free road (m/s)")
    slow_speed: float = Field(default=3.0, gt=0.0, description="speed with an obstacle ahead (m/s)")
    turn_speed: float = Field(default=4.0, gt=0.0, description="speed limit while steering hard (m/s)")
    turn_steering: float = Field(default=0.2, gt=0.0, description="steering beyond which turn_speed applies (rad)")
    max_accel: float = Field(default=1.5, gt=0.0, description="acceleration (m/s²)")
    max_decel: float = Field(default=4.0, gt=0.0, description="braking deceleration a_max (m/s²)")
    stop_margin: float = Field(default=2.0, ge=0.0, description="added to v²/(2·a_max) for the stopping distance (m)")
    corridor_half_width: float = Field(default=1.25, gt=0.0, description="half width of the corridor ahead (m)")
    slow_enter: float = Field(default=15.0, gt=0.0, description="an obstacle nearer in the corridor: slow down (m)")
    slow_exit: float = Field(default=20.0, gt=0.0, description="the corridor clear this far: cruise again (m)")
    resume_distance: float = Field(default=8.0, gt=0.0, description="clear corridor needed to drive on after a stop")
    resume_frames: int = Field(default=3, ge=1, description="frames the corridor must stay clear to drive on")
    max_blind_frames: int = Field(default=3, ge=0, description="blind frames coasted through before stopping")
    initial_speed: float = Field(default=0.0, ge=0.0, description="speed at the start of each log (m/s)")
    report_obstacles: bool = Field(default=False, description="return the obstacle cells as boxes with each decision")

    @model_validator(mode="after")
    def _ordered(self) -> ControllerConfig:
        if self.threshold_low > self.threshold_high:
            raise ValueError(f"threshold_low ({self.threshold_low}) must not exceed threshold_high "
                             f"({self.threshold_high})")
        if self.slow_exit < self.slow_enter:
            raise ValueError(f"slow_exit ({self.slow_exit}) must not be below slow_enter ({self.slow_enter})")
        if self.max_height <= self.min_height:
            raise ValueError(f"max_height ({self.max_height}) must exceed min_height ({self.min_height})")
        return self
