"""Regenerate the pictures of ``docs/simulator.md``.

Run from the repository root (needs the ``docs`` extra, i.e. matplotlib)::

    .venv/bin/python docs/scripts/render_simulator.py

Every image is written to ``docs/images/``; everything is deterministic (fixed seeds).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import shapely
from matplotlib.colors import LinearSegmentedColormap, ListedColormap, Normalize
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle
from matplotlib.patches import Polygon as PolygonPatch
from shapely import affinity
from shapely.geometry import LineString, MultiPolygon, Polygon

from lidarfuzz.scene.geometry import bev_corners
from lidarfuzz.sim.generate import generate_scene
from lidarfuzz.sim.materials import SEMANTIC_CLASSES
from lidarfuzz.sim.render import Renderer
from lidarfuzz.sim.sensor import SENSOR_PRESETS
from lidarfuzz.sim.spec import (
    Actor,
    Building,
    Bush,
    Crosswalk,
    Pole,
    SceneSpec,
    Sign,
    Tree,
    Wall,
    load_scene,
    parse_scene,
)
from lidarfuzz.sim.world import compile_world, footprint_of

DOCS = Path(__file__).resolve().parents[1]
IMAGES = DOCS / "images"
SCENES = DOCS / "scenes"
DPI = 100

#: The generated scenes shown on the page: (seed, kind); titles are derived from each scene.
SCENE_SEEDS = [(12, "urban"), (7, "urban"), (21, "suburban")]


def describe(spec: SceneSpec) -> str:
    """A one-line description of a generated scene, read off its description."""
    main = spec.roads[0]
    kind = spec.name.split("-")[0]
    parts = [f"{kind}, {main.lanes}-lane road"]
    parts.append("with parking strips" if main.parking_width else "without parking strips")
    if len(spec.roads) > 1:
        x = spec.roads[1].centerline[0][0]
        parts.append(f"a junction {abs(x):.0f} m {'ahead' if x > 0 else 'behind'}")
    return ", ".join(parts)
SENSOR_SEED = 12  # the scene the sensor presets are compared on

CROP_X = (-40.0, 70.0)
CROP_Y = (-35.0, 35.0)

CLASS_COLOURS = {
    "Car": "#3f7df4", "Van": "#17becf", "Truck": "#9b59d0", "Pedestrian": "#e8208f", "Cyclist": "#ff8c00",
    "DontCare": "#9a9a9a",
}
SEMANTIC_COLOURS = {
    "unlabelled": "#777777", "road": "#4d4d4d", "lane-marking": "#f2f2f2", "sidewalk": "#9c7fb0",
    "terrain": "#7d8f3a", "building": "#d8b48a", "wall": "#c0504d", "vegetation": "#2fae4e", "trunk": "#8b5a2b",
    "pole": "#ffe119", "traffic-sign": "#ff3b3b", "car": "#5b8cff", "van": "#42d4f4", "truck": "#c77dff",
    "pedestrian": "#ff4fd8", "cyclist": "#ff8c1a", "other-ground": "#a89f91",
}
SEMANTIC_CMAP = ListedColormap([SEMANTIC_COLOURS[name] for name in SEMANTIC_CLASSES])
#: Bright on a dark background at both ends (turbo without its darkest tails).
BRIGHT_TURBO = ListedColormap(plt.get_cmap("turbo")(np.linspace(0.08, 0.92, 256)))
DEPTH_CMAP = ListedColormap(BRIGHT_TURBO.colors[::-1])
#: Sweep time: start (blue) and end (red) differ, the forward-facing instant is white.
TIME_CMAP = LinearSegmentedColormap.from_list("sweep", ["#2f8fff", "#e6e6e6", "#ff3b3b"])
DARK = "#101418"

plt.rcParams.update({
    "font.size": 9, "axes.titlesize": 10, "axes.labelsize": 9, "legend.fontsize": 7.5, "figure.dpi": DPI,
    "savefig.dpi": DPI,
})


# --------------------------------------------------------------------------- helpers
def render(spec: SceneSpec, t_ref: float = 0.0):
    """(renderer, scene) for ``spec`` at ``t_ref``."""
    renderer = Renderer(compile_world(spec))
    return renderer, renderer.render(t_ref, frame_id="000000")


def world_to_lidar(renderer: Renderer, t_ref: float = 0.0) -> list[float]:
    """Shapely affine parameters [a, b, d, e, xoff, yoff] taking world x, y to the LiDAR frame at ``t_ref``."""
    inverse = np.linalg.inv(renderer.pose_matrix(t_ref))
    return [inverse[0, 0], inverse[0, 1], inverse[1, 0], inverse[1, 1], inverse[0, 3], inverse[1, 3]]


def polygons(geometry) -> list[Polygon]:
    if geometry.is_empty:
        return []
    if isinstance(geometry, Polygon):
        return [geometry]
    if isinstance(geometry, MultiPolygon):
        return list(geometry.geoms)
    return [g for g in getattr(geometry, "geoms", []) if isinstance(g, Polygon)]


def fill(ax, geometry, **style) -> None:
    """Draw (multi)polygons, holes included, as matplotlib patches."""
    from matplotlib.patches import PathPatch
    from matplotlib.path import Path as MplPath

    for poly in polygons(geometry):
        rings = [np.asarray(poly.exterior.coords)] + [np.asarray(r.coords) for r in poly.interiors]
        vertices = np.concatenate(rings)
        codes = np.concatenate([[MplPath.MOVETO] + [MplPath.LINETO] * (len(r) - 2) + [MplPath.CLOSEPOLY]
                                for r in rings])
        ax.add_patch(PathPatch(MplPath(vertices, codes), **style))


def crop(ax, xlim=CROP_X, ylim=CROP_Y) -> None:
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("y (m, left)")


def camera_fov(scene, reach: float = 120.0) -> np.ndarray:
    """The front camera's horizontal field of view in the LiDAR frame: [apex, left edge end, right edge end]."""
    calib = scene.calib
    width = calib.image_shape[1]
    cy = calib.P2[1, 2]
    near = calib.image_to_lidar([[0.0, cy], [width - 1.0, cy]], [0.01, 0.01])
    far = calib.image_to_lidar([[0.0, cy], [width - 1.0, cy]], [reach, reach])
    apex = near.mean(axis=0)
    return np.array([apex[:2], far[0, :2], far[1, :2]])


def draw_fov(ax, scene, colour: str) -> None:
    apex, left, right = camera_fov(scene)
    for end in (left, right):
        ax.plot([apex[0], end[0]], [apex[1], end[1]], ls=(0, (4, 3)), lw=0.8, color=colour, zorder=6)


def labelled(scene):
    """Boxes with a 3D geometry (DontCare regions excluded): (M×7 array, class names)."""
    keep = scene.boxes.has_geometry
    return scene.boxes.as_array()[keep], np.asarray(scene.boxes.labels)[keep]


def draw_boxes_bev(ax, boxes: np.ndarray, names: np.ndarray, lw: float = 1.1) -> None:
    for corners, box, name in zip(bev_corners(boxes), boxes, names, strict=True):
        colour = CLASS_COLOURS.get(str(name), "white")
        ax.add_patch(PolygonPatch(corners, closed=True, fill=False, ec=colour, lw=lw, zorder=8))
        front = corners[[0, 1]].mean(axis=0)  # bev_corners starts front-right, front-left
        ax.plot([box[0], front[0]], [box[1], front[1]], color=colour, lw=lw, zorder=8)


# --------------------------------------------------------------------------- 1. layout
def draw_layout(ax, spec: SceneSpec, renderer: Renderer, scene) -> None:
    """The scene description seen from above, in the LiDAR frame of the frame's timestamp."""
    world = renderer.world
    params = world_to_lidar(renderer)

    def tf(geometry):
        return affinity.affine_transform(geometry, params)

    ground = {"grass": "#dfe9cf", "soil": "#e6dccb", "paving": "#e4e1db"}[spec.ground]
    ax.set_facecolor(ground)
    fill(ax, tf(world.ground.sidewalks), fc="#cfc7bd", ec="#a89f94", lw=0.5, zorder=1)
    fill(ax, tf(world.drivable), fc="#8f9296", ec="none", zorder=2)
    for road in spec.roads:
        centre = LineString(road.centerline)
        if road.parking_width > 0:
            strips = centre.buffer(road.half_width, cap_style="flat").difference(
                centre.buffer(road.carriageway_half_width, cap_style="flat"))
            fill(ax, tf(strips.intersection(world.drivable)), fc="#a6a9ad", ec="none", zorder=2)
        others = shapely.union_all([LineString(r.centerline).buffer(r.half_width + 1.0, cap_style="flat")
                                    for r in spec.roads if r is not road] or [Polygon()])
        half = road.carriageway_half_width
        for lane in range(road.lanes + 1):
            offset = -half + lane * road.lane_width
            line = centre.offset_curve(offset) if abs(offset) > 1e-6 else centre
            line = tf(line.difference(others))
            edge = lane in (0, road.lanes)
            centre_line = abs(offset) < 1e-6 and not road.one_way
            style = "-" if (edge or centre_line) else (0, (3, 6))
            for part in getattr(line, "geoms", [line]):
                if part.is_empty:
                    continue
                xy = np.asarray(part.coords)
                ax.plot(xy[:, 0], xy[:, 1], color="white", lw=0.6, ls=style, zorder=3)

    for obj in spec.objects:
        if isinstance(obj, Crosswalk):
            yaw = np.deg2rad(obj.yaw)
            along = np.array([np.cos(yaw), np.sin(yaw)])
            across = np.array([-along[1], along[0]])
            for offset in np.arange(-obj.length / 2 + 0.25, obj.length / 2, 1.0):
                centre = np.asarray(obj.position) + offset * across
                bar = LineString([centre - along * obj.width / 2, centre + along * obj.width / 2]).buffer(
                    0.25, cap_style="flat")
                fill(ax, tf(bar), fc="white", ec="none", zorder=3)
    heights = Normalize(4, 24)
    building_cmap = plt.get_cmap("copper_r")
    for obj in spec.objects:
        shape = tf(footprint_of(obj)) if not isinstance(obj, Crosswalk) else None
        if isinstance(obj, Building):
            colour = building_cmap(0.15 + 0.6 * heights(obj.height))
            fill(ax, shape, fc=colour, ec="#4a3826", lw=0.6, zorder=4)
        elif isinstance(obj, Wall):
            fill(ax, shape.buffer(0.15), fc="#7a4e2d" if obj.material == "fence" else "#5a5a5a", ec="none",
                 zorder=4)
        elif isinstance(obj, Bush):
            fill(ax, shape, fc="#4f8f3a", ec="none", alpha=0.9, zorder=4)
        elif isinstance(obj, Tree):
            canopy = tf(shapely.Point(obj.position).buffer(obj.canopy_radius))
            fill(ax, canopy, fc="#2e8b3a", ec="#1d5e26", lw=0.4, alpha=0.55, zorder=5)
        elif isinstance(obj, Pole):
            p = np.asarray(tf(shapely.Point(obj.position)).coords)[0]
            if obj.arm > 0:
                tip = np.asarray(tf(shapely.Point(np.asarray(obj.position) + obj.arm * np.array(
                    [np.cos(np.deg2rad(obj.yaw)), np.sin(np.deg2rad(obj.yaw))]))).coords)[0]
                ax.plot([p[0], tip[0]], [p[1], tip[1]], color="black", lw=0.8, zorder=6)
            ax.plot(*p, "o", ms=2.6, color="black", zorder=6)
        elif isinstance(obj, Sign):
            p = np.asarray(tf(shapely.Point(obj.position)).coords)[0]
            ax.plot(*p, "^", ms=4.5, mfc="#e0252b", mec="white", mew=0.5, zorder=6)

    for actor in spec.actors:
        shape = tf(footprint_of(actor))
        colour = CLASS_COLOURS[actor.cls]
        style = {"fc": colour, "ec": "black", "lw": 0.5, "zorder": 7}
        if actor.parked:
            style.update(fc="white", ec=colour, lw=1.2, hatch="/////")
        fill(ax, shape, **style)
        _heading_marker(ax, tf, actor)

    # The ego vehicle and its sensor.
    ego = tf(footprint_of(Actor.model_validate({"class": "Car", "position": spec.ego.position, "yaw": spec.ego.yaw,
                                                "size": (4.4, 1.9, 1.6)})))
    fill(ax, ego, fc="black", ec="white", lw=0.8, zorder=9)
    ax.annotate("", xy=(6.5, 0), xytext=(0.5, 0), zorder=10,
                arrowprops={"arrowstyle": "-|>", "color": "white", "lw": 1.4, "mutation_scale": 10})
    draw_fov(ax, scene, "#333333")
    crop(ax)

    handles = [Patch(fc=CLASS_COLOURS[c], ec="black", lw=0.5, label=c) for c in
               ("Car", "Van", "Truck", "Pedestrian", "Cyclist") if any(a.cls == c for a in spec.actors)]
    handles += [
        Patch(fc="white", ec="#555555", hatch="/////", label="parked"),
        Patch(fc="black", ec="white", label="ego (sensor at its centre)"),
        Patch(fc=building_cmap(0.5), ec="#4a3826", label="building (darker = taller)"),
        Patch(fc="#8cbf90", ec="#1d5e26", lw=0.4, label="tree canopy"),
        Line2D([], [], marker="o", ls="none", color="black", ms=3, label="lamp post"),
        Line2D([], [], marker="^", ls="none", mfc="#e0252b", mec="white", ms=5, label="sign"),
        Line2D([], [], ls=(0, (4, 3)), color="#333333", lw=0.8, label="camera field of view"),
    ]
    ax.legend(handles=handles, loc="lower left", ncols=2, framealpha=0.85, handlelength=1.4, borderpad=0.4,
              columnspacing=0.8, fontsize=6.5)


def _heading_marker(ax, tf, actor: Actor) -> None:
    """For a moving actor, an arrow from its centre: where it will be in one second."""
    yaw = np.deg2rad(actor.yaw)
    direction = np.array([np.cos(yaw), np.sin(yaw)])
    start = np.asarray(actor.position)
    if actor.speed > 0 and not actor.parked:
        end = start + direction * actor.speed
        a, b = (np.asarray(tf(shapely.Point(p)).coords)[0] for p in (start, end))
        ax.annotate("", xy=b, xytext=a, zorder=8,
                    arrowprops={"arrowstyle": "-|>", "color": "black", "lw": 0.7, "mutation_scale": 6})


# --------------------------------------------------------------------------- 2. bird's-eye view
def draw_bev(ax, scene, colour_by: str = "label", boxes: bool = True, size: float = 0.25,
             xlim=CROP_X, ylim=CROP_Y, legend: bool = True):
    points = scene.points
    xyz = points.data[:, :3]
    inside = (xyz[:, 0] > xlim[0]) & (xyz[:, 0] < xlim[1]) & (xyz[:, 1] > ylim[0]) & (xyz[:, 1] < ylim[1])
    xyz = xyz[inside]
    order = np.argsort(xyz[:, 2])  # higher points are drawn on top, as seen from above
    xyz = xyz[order]
    ax.set_facecolor(DARK)
    mappable = None
    if colour_by == "label":
        label = points.channel("label")[inside][order].astype(int)
        ax.scatter(xyz[:, 0], xyz[:, 1], c=label, cmap=SEMANTIC_CMAP, vmin=-0.5, vmax=len(SEMANTIC_CLASSES) - 0.5,
                   s=size, lw=0, rasterized=True)
        if legend:
            present = [SEMANTIC_CLASSES[i] for i in np.unique(label)]
            handles = [Line2D([], [], marker="s", ls="none", ms=5, color=SEMANTIC_COLOURS[name], label=name)
                       for name in present]
            ax.legend(handles=handles, loc="lower left", ncols=3, fontsize=6.5, framealpha=0.75, facecolor="#2a2f35",
                      labelcolor="white", edgecolor="none", handletextpad=0.2, columnspacing=0.6, borderpad=0.4)
    elif colour_by == "height":
        height = xyz[:, 2] + scene_mount_height(scene)
        mappable = ax.scatter(xyz[:, 0], xyz[:, 1], c=height, cmap=BRIGHT_TURBO, vmin=-0.2, vmax=6.0, s=size, lw=0,
                              rasterized=True)
    elif colour_by == "time":
        t = points.channel("time")[inside][order] * 1000.0
        mappable = ax.scatter(xyz[:, 0], xyz[:, 1], c=t, cmap=TIME_CMAP, vmin=-50, vmax=50, s=size, lw=0,
                              rasterized=True)
    if boxes:
        arr, names = labelled(scene)
        draw_boxes_bev(ax, arr, names)
    crop(ax, xlim, ylim)
    return mappable


def scene_mount_height(scene) -> float:
    return float(SENSOR_PRESETS.get(scene.metadata.get("sensor", ""), SENSOR_PRESETS["HDL-64E"]).mount_height)


# --------------------------------------------------------------------------- 3. camera view
def draw_camera(ax, scene, max_depth: float = 60.0):
    calib = scene.calib
    height, width = calib.image_shape
    uv, depth = calib.lidar_to_image(scene.points.data[:, :3])
    keep = (depth > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0) & (uv[:, 1] < height)
    uv, depth = uv[keep], depth[keep]
    order = np.argsort(-depth)  # near points on top
    ax.set_facecolor("black")
    mappable = ax.scatter(uv[order, 0], uv[order, 1], c=depth[order], cmap=DEPTH_CMAP, vmin=0, vmax=max_depth, s=0.9,
                          lw=0, rasterized=True)
    for box2d, name, occlusion in zip(scene.boxes.bbox2d, scene.boxes.labels, scene.boxes.occlusion, strict=True):
        if not np.all(np.isfinite(box2d)):
            continue
        x1, y1, x2, y2 = box2d
        colour = CLASS_COLOURS.get(str(name), "white")
        dontcare = str(name) == "DontCare"
        ax.add_patch(Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, ec=colour, lw=0.7 if dontcare else 1.2,
                               ls=(0, (2, 2)) if dontcare else "-", zorder=5))
        if y2 - y1 >= 24 and not dontcare:  # small boxes: the colour tells the class
            ax.text(x1 + 2, y1 + 2, f"{name} {int(occlusion)}", color="white", fontsize=6.5, va="top", zorder=6,
                    clip_on=True, bbox={"fc": colour, "ec": "none", "pad": 0.8, "alpha": 0.85})
    handles = [Patch(fc="none", ec=CLASS_COLOURS[c], lw=1.2, label=c) for c in CLASS_COLOURS if c != "DontCare"]
    handles.append(Patch(fc="none", ec=CLASS_COLOURS["DontCare"], ls=(0, (2, 2)), label="DontCare"))
    ax.legend(handles=handles, loc="upper left", ncols=6, fontsize=7, framealpha=0.7, facecolor="#222222",
              edgecolor="none", labelcolor="white", handlelength=1.2, columnspacing=1.0)
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    return mappable


# --------------------------------------------------------------------------- figures
def scene_figure(spec: SceneSpec, path: Path, title: str) -> dict[str, object]:
    renderer, scene = render(spec)
    fig = plt.figure(figsize=(13.5, 9.6))
    grid = fig.add_gridspec(2, 2, height_ratios=[1.0, 0.78], hspace=0.14, wspace=0.1, left=0.05, right=0.955,
                            top=0.945, bottom=0.05)
    ax_layout = fig.add_subplot(grid[0, 0])
    ax_bev = fig.add_subplot(grid[0, 1])
    ax_cam = fig.add_subplot(grid[1, :])
    draw_layout(ax_layout, spec, renderer, scene)
    ax_layout.set_title("scene description (from above)")
    draw_bev(ax_bev, scene, size=0.5)
    draw_fov(ax_bev, scene, "#bbbbbb")
    ax_bev.set_title("point cloud, coloured by semantic label; labelled 3D boxes")
    ax_bev.set_ylabel("")
    mappable = draw_camera(ax_cam, scene)
    ax_cam.set_title("points projected into the front camera image (1242 × 375 px), coloured by depth; "
                     "the labels' 2D boxes with class and occlusion level")
    bar = fig.colorbar(mappable, ax=ax_cam, fraction=0.025, pad=0.008, aspect=12)
    bar.set_label("depth (m)")
    counts = {str(c): int(n) for c, n in zip(*np.unique(scene.boxes.labels, return_counts=True), strict=True)}
    summary = ", ".join(f"{n} {c}" for c, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    fig.suptitle(f"{title} — {spec.sensor if isinstance(spec.sensor, str) else spec.sensor.name}, "
                 f"ego {spec.ego.speed:.1f} m/s, {len(scene.points):,} points; labels: {summary}", fontsize=11)
    save(fig, path)
    return {"points": len(scene.points), "labels": counts}


def sensors_figure(seed: int, path: Path) -> dict[str, int]:
    base = generate_scene(seed)
    fig, axes = plt.subplots(2, 2, figsize=(13.5, 9.6), sharex=True, sharey=True,
                             gridspec_kw={"hspace": 0.12, "wspace": 0.04, "left": 0.05, "right": 0.93, "top": 0.94,
                                          "bottom": 0.05})
    counts = {}
    mappable = None
    for ax, name in zip(axes.ravel(), SENSOR_PRESETS, strict=True):
        sensor = SENSOR_PRESETS[name]
        _, scene = render(base.model_copy(update={"sensor": name}))
        mappable = draw_bev(ax, scene, colour_by="height", size=0.7)
        counts[name] = len(scene.points)
        elev = np.asarray(sensor.elevations_deg)
        ax.set_title(f"{name}: {sensor.beams} beams {elev.max():+.1f}° … {elev.min():+.1f}°, "
                     f"{sensor.columns} columns — {len(scene.points):,} points, {len(labelled(scene)[0])} labelled")
        if ax in axes[0]:
            ax.set_xlabel("")
        if ax in axes[:, 1]:
            ax.set_ylabel("")
    cax = fig.add_axes((0.94, 0.25, 0.012, 0.5))
    fig.colorbar(mappable, cax=cax).set_label("height above the road (m)")
    fig.suptitle(f"The four sensor presets on one scene (seed {seed}), coloured by height", fontsize=11)
    save(fig, path)
    return counts


def beams_figure(path: Path) -> None:
    """Side view of each preset's beam fan: which beams reach a car at 15 m and a pedestrian at 30 m."""
    fig, axes = plt.subplots(4, 1, figsize=(13.5, 8.2), sharex=True,
                             gridspec_kw={"hspace": 0.35, "left": 0.05, "right": 0.98, "top": 0.94, "bottom": 0.07})
    car = (15.0, 3.9, 1.53)
    ped = (30.0, 0.6, 1.76)
    for ax, (name, sensor) in zip(axes, SENSOR_PRESETS.items(), strict=True):
        h = sensor.mount_height
        elev = np.deg2rad(np.sort(sensor.elevations_deg))
        reach = 70.0
        hits = {"car": 0, "ped": 0}
        for e in elev:
            # Where the beam meets the ground (z = 0), else at the right edge.
            distance = h / -np.tan(e) if e < 0 else np.inf
            end = min(distance, reach)
            ax.plot([0, end], [h, h + np.tan(e) * end], color="#2b6cb0", lw=0.45, alpha=0.8)
            if distance < reach:
                ax.plot(distance, 0, "|", color="#2b6cb0", ms=4, mew=0.8)
            for key, (x0, _length, height) in (("car", car), ("ped", ped)):
                z = h + np.tan(e) * x0
                hits[key] += int(0.0 <= z <= height)  # the beam reaches the near face
        ax.add_patch(Rectangle((car[0], 0), car[1], car[2], fc=CLASS_COLOURS["Car"], alpha=0.7, ec="none"))
        ax.add_patch(Rectangle((ped[0], 0), ped[1], ped[2], fc=CLASS_COLOURS["Pedestrian"], alpha=0.8, ec="none"))
        ax.text(car[0] + car[1] / 2, car[2] + 0.25, f"car: {hits['car']} beams", ha="center", fontsize=7.5)
        ax.text(ped[0] + ped[1] / 2, ped[2] + 0.25, f"pedestrian: {hits['ped']} beams", ha="center", fontsize=7.5)
        ax.plot(0, h, "o", color="black", ms=4)
        ax.axhline(0, color="#666666", lw=0.8)
        ax.set_ylim(-0.3, 6.0)
        ax.set_xlim(-1, reach)
        ax.set_aspect("equal")
        ax.set_ylabel("z (m)")
        ax.set_title(f"{name}: {sensor.beams} beams, sensor {h:.2f} m above the road; | = where a beam meets "
                     "the ground", fontsize=9, loc="left")
    axes[-1].set_xlabel("distance ahead (m)")
    fig.suptitle("Beam fans of the sensor presets, side view (true to scale)", fontsize=11)
    save(fig, path)


#: A stationary showroom: one road user of each class on open ground, seen from close range.
SHOWROOM = {
    "name": "showroom",
    "ground": "soil",
    "actors": [
        {"class": "Car", "position": [7.0, 4.5], "yaw": 160.0},
        {"class": "Van", "position": [8.0, -5.5], "yaw": 200.0},
        {"class": "Truck", "position": [-4.0, 11.0], "yaw": 180.0},
        {"class": "Pedestrian", "position": [-5.0, -3.0], "yaw": 90.0},
        {"class": "Cyclist", "position": [-3.0, -7.0], "yaw": 0.0},
    ],
}


def classes_figure(path: Path) -> dict[str, int]:
    spec = parse_scene(SHOWROOM)
    renderer, scene = render(spec)
    mount = renderer.sensor.mount_height
    instance = scene.points.channel("instance").astype(int)
    xyz = scene.points.data[:, :3].astype(np.float64)
    intensity = scene.points.channel("intensity")
    fig, axes = plt.subplots(3, 5, figsize=(13.5, 8.4),
                             gridspec_kw={"hspace": 0.32, "wspace": 0.28, "left": 0.05, "right": 0.92, "top": 0.9,
                                          "bottom": 0.06, "height_ratios": [1.0, 0.9, 0.9]})
    counts = {}
    mappable = None
    for col, actor in enumerate(spec.actors):
        placed = renderer.world.actors[col]
        length, width, height = placed.size
        mine = instance == placed.track_id
        p = xyz[mine]
        yaw = np.deg2rad(actor.yaw)
        dx, dy = p[:, 0] - actor.position[0], p[:, 1] - actor.position[1]
        local = np.column_stack([np.cos(yaw) * dx + np.sin(yaw) * dy, -np.sin(yaw) * dx + np.cos(yaw) * dy,
                                 p[:, 2] + mount])
        counts[actor.cls] = int(mine.sum())
        distance = float(np.hypot(*actor.position))
        # (title, horizontal axis, vertical axis, their extents, labels, nearness to the viewer)
        views = (("top view", 0, 1, length, width, "x (m, forward)", "y (m, left)", local[:, 2]),
                 ("side view (from the right)", 0, 2, length, height, "x (m, forward)", "z (m)", -local[:, 1]),
                 ("front view", 1, 2, width, height, "y (m, left)", "z (m)", local[:, 0]))
        for row, (label, a, b, extent_a, extent_b, xlabel, ylabel, nearness) in enumerate(views):
            ax = axes[row, col]
            order = np.argsort(nearness)  # the viewer's nearest points are drawn last
            mappable = ax.scatter(local[order, a], local[order, b], c=intensity[mine][order], cmap="plasma", vmin=0,
                                  vmax=0.9, s=3.0 if actor.cls != "Truck" else 1.2, lw=0)
            lo_b = 0.0 if b == 2 else -extent_b / 2
            ax.add_patch(Rectangle((-extent_a / 2, lo_b), extent_a, extent_b, fill=False, ec="#555555", lw=0.7,
                                   ls=(0, (3, 2))))
            pad = 0.15 * max(extent_a, extent_b)
            ax.set_xlim(-extent_a / 2 - pad, extent_a / 2 + pad)
            ax.set_ylim(lo_b - pad, lo_b + extent_b + pad)
            ax.set_aspect("equal")
            ax.set_xlabel(xlabel, fontsize=7.5)
            ax.set_ylabel(ylabel, fontsize=7.5)
            ax.tick_params(labelsize=7)
            ax.set_facecolor("#f4f4f4")
            if row == 0:
                ax.set_title(f"{actor.cls}: {mine.sum():,} points at {distance:.0f} m\n{label}", fontsize=9)
            else:
                ax.set_title(label, fontsize=8)
    cax = fig.add_axes((0.935, 0.3, 0.01, 0.4))
    fig.colorbar(mappable, cax=cax).set_label("intensity")
    fig.suptitle("Part-based road users (HDL-64E, stationary, 6–12 m away), in each object's own frame; "
                 "dashed: the label box", fontsize=11)
    save(fig, path)
    return counts


def rolling_shutter_figure(path: Path) -> dict[str, float]:
    """The same hand-written scene with the ego standing and driving at 15 m/s."""
    base = load_scene(SCENES / "t_junction_behind.yaml")
    fig = plt.figure(figsize=(13.5, 11.4))
    grid = fig.add_gridspec(3, 2, height_ratios=[2.6, 3.0, 3.0], hspace=0.32, wspace=0.12, left=0.06, right=0.92,
                            top=0.94, bottom=0.05)
    zoom_x, zoom_y = (-42.0, -6.0), (-5.0, 5.0)
    mappable = None
    info = {}
    for col, speed in enumerate((0.0, 15.0)):
        spec = base.model_copy(update={"ego": base.ego.model_copy(update={"speed": speed})})
        renderer, scene = render(spec)
        ax = fig.add_subplot(grid[0, col])
        mappable = draw_bev(ax, scene, colour_by="time", boxes=True, size=0.6, xlim=(-45, 45), ylim=(-20, 20))
        ax.add_patch(Rectangle((zoom_x[0], zoom_y[0]), zoom_x[1] - zoom_x[0], zoom_y[1] - zoom_y[0], fill=False,
                               ec="white", lw=0.8, ls=(0, (3, 2))))
        ax.set_title(f"ego at {speed:.0f} m/s: the whole sweep")
        zoom = fig.add_subplot(grid[1 + col, :])
        draw_bev(zoom, scene, colour_by="time", boxes=False, size=4.0, xlim=zoom_x, ylim=zoom_y)
        params = world_to_lidar(renderer)
        follower = affinity.affine_transform(footprint_of(spec.actors[0]), params)
        fill(zoom, follower, fc="none", ec="white", lw=0.8, ls=(0, (3, 2)), zorder=9)
        for xy, text_xy, text in (((-38.0, 1.0), (-41.6, 3.4), "building\nfacade"),
                                  ((-35.8, 0.2), (-34.6, 3.4), "lamp post"),
                                  ((-12.0, 0.9), (-17.5, 3.4), "following car\nat t = 0")):
            zoom.annotate(text, xy, xytext=text_xy, color="white", fontsize=8, ha="left", va="center",
                          bbox={"fc": DARK, "ec": "none", "pad": 1},
                          arrowprops={"arrowstyle": "-", "color": "#cccccc", "lw": 0.7})
        zoom.set_title(f"ego at {speed:.0f} m/s: zoom behind the car (dashed box above)")
        info[f"{speed:.0f} m/s points"] = len(scene.points)
    cax = fig.add_axes((0.935, 0.3, 0.01, 0.4))
    fig.colorbar(mappable, cax=cax).set_label("point time relative to the frame timestamp (ms)")
    fig.suptitle("Rolling shutter: the head turns clockwise from straight behind (−50 ms) through the front (0) "
                 "back to straight behind (+50 ms)", fontsize=11)
    save(fig, path)
    return info


# KITTI object-benchmark training 000000–000002 (HDL-64E), measured once (never read here).
#: Share of returns per intensity bin of 0.05 (0–1).
KITTI_INTENSITY_HISTOGRAMS = (
    (0.109, 0.018, 0.038, 0.067, 0.076, 0.148, 0.207, 0.168, 0.080, 0.044, 0.024, 0.013, 0.005, 0.001, 0.001),
    (0.100, 0.037, 0.053, 0.126, 0.129, 0.195, 0.173, 0.092, 0.038, 0.024, 0.015, 0.010, 0.004, 0.002, 0.001),
    (0.095, 0.021, 0.047, 0.084, 0.082, 0.171, 0.210, 0.144, 0.064, 0.039, 0.020, 0.010, 0.006, 0.002, 0.002),
)
#: Share of returns reading exactly 0 per range bin (m).
KITTI_ZERO_BY_RANGE = {
    (0, 10): (0.106, 0.046, 0.077), (10, 20): (0.079, 0.032, 0.047), (20, 30): (0.119, 0.084, 0.098),
    (30, 40): (0.156, 0.232, 0.429), (40, 60): (0.504, 0.654, 0.579), (60, 80): (0.877, 0.940, 0.940),
}
#: Height of the road ahead and behind (5th percentile of z within 4 m of the x axis, 5 m bins from x = −40 m).
KITTI_GROUND_PROFILES = {
    "000001": (-2.38, -2.32, -2.21, -2.13, -2.05, -1.98, -1.87, -1.82, -1.75, -1.69, -1.64, -1.60, -1.54, -1.46,
               -1.38, -1.32, -1.23, -1.25),
    "000002": (-2.22, -2.06, -1.99, -1.93, -1.90, -1.85, -1.80, -1.74, -1.72, -1.73, -1.98, -1.94, -1.93, -2.01,
               -2.09, -2.20, -2.33, np.nan),
}


def realism_figure(path: Path) -> dict[str, object]:
    """Intensities and ground of simulated HDL-64E frames next to KITTI's."""
    from lidarfuzz.sim import GenerationConfig, render_frames
    from lidarfuzz.sim.realism import RealismConfig

    frames = {"realistic (default)": list(render_frames(GenerationConfig(frames=4, seed=11))),
              "RealismConfig.off()": list(render_frames(GenerationConfig(frames=4, seed=11,
                                                                         realism=RealismConfig.off())))}
    colours = {"realistic (default)": "#d62728", "RealismConfig.off()": "#7f7f7f"}
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4), layout="constrained")
    edges = np.linspace(0, 0.75, 16)
    centres = (edges[:-1] + edges[1:]) / 2
    ax = axes[0]
    for k, hist in enumerate(KITTI_INTENSITY_HISTOGRAMS):
        ax.plot(centres, hist, color="#1f77b4", lw=1.2, alpha=0.8, label="KITTI 000000–000002" if k == 0 else None)
    info: dict[str, object] = {}
    for name, scenes in frames.items():
        intensity = np.concatenate([s.points.channel("intensity") for s in scenes])
        share = np.histogram(intensity, bins=np.linspace(0, 1, 21))[0][:15] / len(intensity)
        ax.plot(centres, share, color=colours[name], lw=1.8, label=f"simulator, {name}")
        info[name] = {"zero": round(float(np.mean(intensity == 0)), 3),
                      "points": int(np.mean([len(s.points) for s in scenes]))}
    ax.set(xlabel="intensity", ylabel="share of returns per 0.05", title="Intensity histogram")
    ax.legend(fontsize=8)
    ax = axes[1]
    bins = list(KITTI_ZERO_BY_RANGE)
    x = np.arange(len(bins))
    for k in range(3):
        ax.plot(x, [KITTI_ZERO_BY_RANGE[b][k] for b in bins], "o-", color="#1f77b4", alpha=0.8,
                label="KITTI 000000–000002" if k == 0 else None)
    for name, scenes in frames.items():
        intensity = np.concatenate([s.points.channel("intensity") for s in scenes])
        distance = np.concatenate([np.linalg.norm(s.points.xyz, axis=1) for s in scenes])
        zero = [np.mean(intensity[(distance >= lo) & (distance < hi)] == 0) for lo, hi in bins]
        ax.plot(x, zero, "s-", color=colours[name], label=f"simulator, {name}")
    ax.set_xticks(x, [f"{lo}–{hi}" for lo, hi in bins])
    ax.set(xlabel="range (m)", ylabel="share reading exactly 0", title="Zero readings by range", ylim=(-0.02, 1.02))
    ax.legend(fontsize=8)
    ax = axes[2]
    bin_x = np.arange(-40, 50, 5) + 2.5
    for k, profile in enumerate(KITTI_GROUND_PROFILES.values()):
        ax.plot(bin_x, profile, "o-", color="#1f77b4", alpha=0.8, label="KITTI 000001, 000002" if k == 0 else None)
    for shown, scene in enumerate(frames["realistic (default)"]):
        label, xyz = scene.points.channel("label"), scene.points.xyz
        road = np.isin(label, [1, 2]) & (np.abs(xyz[:, 1]) < 4)
        z = [np.percentile(xyz[road & (np.abs(xyz[:, 0] - c) < 2.5), 2], 5) if np.sum(
            road & (np.abs(xyz[:, 0] - c) < 2.5)) > 20 else np.nan for c in bin_x]
        ax.plot(bin_x, z, "s-", color=colours["realistic (default)"], alpha=0.8,
                label="simulator, realistic (4 frames)" if shown == 0 else None)
    ax.axhline(-1.73, color=colours["RealismConfig.off()"], lw=1.8, label="simulator, RealismConfig.off()")
    ax.set(xlabel="x (m, ahead of the sensor)", ylabel="road height in the sensor frame (m)",
           title="The road ahead and behind")
    ax.legend(fontsize=8)
    fig.suptitle("Simulated HDL-64E frames (GenerationConfig seed 11) next to real KITTI scans", fontsize=11)
    save(fig, path)
    return info


def save(fig, path: Path) -> None:
    """Write ``fig`` as a 256-colour PNG (about a quarter of the size of a true-colour one)."""
    from io import BytesIO

    from PIL import Image

    buffer = BytesIO()
    fig.savefig(buffer, format="png", dpi=DPI, facecolor="white")
    plt.close(fig)
    buffer.seek(0)
    with Image.open(buffer) as image:
        image.convert("RGB").quantize(colors=256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE).save(
            path, optimize=True)
    size = path.stat().st_size / 1024
    print(f"  {path.relative_to(DOCS.parent)}  {size:.0f} KB", flush=True)


def main() -> int:
    started = time.perf_counter()
    IMAGES.mkdir(parents=True, exist_ok=True)
    for seed, kind in SCENE_SEEDS:
        spec = generate_scene(seed)
        assert spec.name == f"{kind}-{seed}", spec.name
        result = scene_figure(spec, IMAGES / f"sim_scene_{kind}_{seed}.png", f"seed {seed}: {describe(spec)}")
        print(f"    {result}")
    example = load_scene(SCENES / "pedestrian_behind_van.yaml")
    print(f"    {scene_figure(example, IMAGES / 'sim_scene_pedestrian_behind_van.png', 'pedestrian_behind_van.yaml')}")
    print(f"    {sensors_figure(SENSOR_SEED, IMAGES / 'sim_sensors.png')}")
    beams_figure(IMAGES / "sim_beams.png")
    print(f"    {classes_figure(IMAGES / 'sim_classes.png')}")
    print(f"    {rolling_shutter_figure(IMAGES / 'sim_rolling_shutter.png')}")
    print(f"    {realism_figure(IMAGES / 'sim_realism.png')}")
    print(f"done in {time.perf_counter() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
