"""The web app's security rules, each in one place (and each with a test in ``tests/web``).

* Binding: 127.0.0.1 by default; any other host needs a token (:func:`~.guard.is_loopback`).
* Token: with one, every ``/api`` call carries ``Authorization: Bearer T`` or ``?token=T``,
  compared in constant time (:mod:`.tokens`).
* Without a token the app answers only requests addressed to a loopback name (a web page
  cannot reach it through DNS rebinding), and state-changing calls from another origin are
  refused (a page cannot post a form to it): :class:`~.guard.RequestGuard`. With a token
  neither is needed: no other site can add the ``Authorization`` header.
* Uploads: a size limit per request (:class:`~.limits.Limits`), checked on ``Content-Length``
  and again while the body streams in (:class:`~.guard.RequestGuard`); zip members checked
  before anything is extracted — absolute paths, ``..``, links, member count and total
  uncompressed size (:mod:`.zips`); files stored under ``<workspace>/uploads/<generated id>/``
  with sanitised names (:func:`~.paths.safe_component`) and never executed.
* Names and frame ids in paths: plain names only (:func:`~.paths.check_name`,
  :func:`~.paths.check_frame_id`).
* Systems under test: ``subprocess:`` and ``worker:`` specs, and options that name code or
  files outside the uploads, are refused through the API (:mod:`.specs`).

The names below are re-exported here, so a route imports the rules from one place.
"""

from lidarfuzz.web.security.guard import RequestGuard, UploadTooLarge, is_loopback
from lidarfuzz.web.security.limits import GiB, Limits, MiB, format_bytes
from lidarfuzz.web.security.paths import check_frame_id, check_name, remove_tree, safe_component, within
from lidarfuzz.web.security.specs import check_model_spec, check_options
from lidarfuzz.web.security.tokens import token_dependency
from lidarfuzz.web.security.zips import check_zip, extract_zip

__all__ = ["GiB", "Limits", "MiB", "RequestGuard", "UploadTooLarge", "check_frame_id", "check_model_spec",
           "check_name", "check_options", "check_zip", "extract_zip", "format_bytes", "is_loopback", "remove_tree",
           "safe_component", "token_dependency", "within"]
