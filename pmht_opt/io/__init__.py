"""Missions in and out: mission files, exports a drone or GIS tool reads, and imports of points.

* :func:`load_mission` / :func:`save_mission`: a scenario with its constraints, planner settings and
  an optional geo origin, in TOML or JSON (:mod:`pmht_opt.io.mission`); :func:`plan_mission` and
  :func:`order_mission` run one as the library would.
* :func:`export_csv`, :func:`export_geojson`, :func:`export_qgc_plan`: a plan as CSV (one row per
  platform and step), GeoJSON (RFC 7946, cut at the antimeridian, with the plan's zones, areas and
  footprints) and QGroundControl ``.plan`` missions whose legs, as flown, keep the plan's promises
  (:mod:`pmht_opt.io.flight` measures them, :mod:`pmht_opt.io.waypoints` chooses the waypoints).
* :func:`read_points`: locales and starts from CSV or GeoJSON; :func:`read_plan_csv`,
  :func:`read_geojson_paths` and :func:`read_qgc_plan` read exported plans back.
* :func:`example_mission`: the missions shipped with the package.
"""

from pmht_opt.io.csv_ import export_csv, read_plan_csv
from pmht_opt.io.examples import EXAMPLES, example_mission, example_path
from pmht_opt.io.frame import Frame
from pmht_opt.io.geojson import export_geojson, plan_geojson, read_geojson_paths
from pmht_opt.io.mission import Mission, load_mission, mission_from_dict, save_mission
from pmht_opt.io.points import read_points, read_radii
from pmht_opt.io.qgc import export_qgc_plan, qgc_paths, read_qgc_plan
from pmht_opt.io.run import order_mission, plan_mission
from pmht_opt.io.settings import PlannerSettings

__all__ = [
    "EXAMPLES",
    "Frame",
    "Mission",
    "PlannerSettings",
    "example_mission",
    "example_path",
    "export_csv",
    "export_geojson",
    "export_qgc_plan",
    "load_mission",
    "mission_from_dict",
    "order_mission",
    "plan_geojson",
    "plan_mission",
    "qgc_paths",
    "read_geojson_paths",
    "read_plan_csv",
    "read_points",
    "read_qgc_plan",
    "read_radii",
    "save_mission",
]
