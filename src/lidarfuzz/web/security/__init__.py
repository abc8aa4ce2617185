"""The web app's security rules, each in one place (and each with a test in ``tests/web``).

* Binding: 127.0.0.1 by default; any other host needs a token (:func:`~.guard.is_loopback`).
* Token: with one, every ``/api`` call carries ``Authorization: Bearer T`` or ``?token=T``,
  compared in constant time (:mod:`.tokens`); it is never printed, and ``token=`` is redacted
  in every log line (:mod:`.logs`).
* Without a token the app answers only requests addressed to ``localhost`` or a loopback
  address (a web page cannot reach it through DNS rebinding), and a write (POST, PUT, PATCH,
  DELETE) must carry the server's own ``Origin`` (and ``Sec-Fetch-Site: same-origin`` where
  sent): ``Origin: null`` (a sandboxed frame), another site's or none is refused
  (:class:`~.guard.RequestGuard`, :func:`~.guard.cross_site_write`). With a token neither is
  needed: no other site can add the ``Authorization`` header.
* Uploads: a size limit per request (:class:`~.limits.Limits`), checked on ``Content-Length``
  and again while the body streams in (:class:`~.guard.RequestGuard`); zip members checked
  before anything is extracted — absolute paths, ``..``, depth and name length, links, encrypted
  and overlapping members, member count, declared sizes and compression ratios — and every byte
  counted again while extracting (:mod:`.zips`); files stored under ``<workspace>/uploads/<generated id>/``
  with sanitised names (:func:`~.paths.safe_component`) and never executed.
* Names and frame ids in paths: plain names only (:func:`~.paths.check_name`,
  :func:`~.paths.check_frame_id`).
* Systems under test: ``subprocess:`` and ``worker:`` specs, and options that name code or
  files outside the uploads, are refused through the API (:mod:`.specs`).

The names below are re-exported here, so a route imports the rules from one place.
"""

from lidarfuzz.web.security.guard import RequestGuard, UploadTooLarge, cross_site_write, is_loopback, is_loopback_host
from lidarfuzz.web.security.ids import MAX_ID, RowId, check_id
from lidarfuzz.web.security.limits import GiB, Limits, MiB, format_bytes
from lidarfuzz.web.security.logs import install_redaction, redact
from lidarfuzz.web.security.paths import check_frame_id, check_name, remove_tree, safe_component, within
from lidarfuzz.web.security.specs import check_model_spec, check_options
from lidarfuzz.web.security.tokens import token_dependency
from lidarfuzz.web.security.zips import check_zip, extract_zip

__all__ = ["MAX_ID", "GiB", "Limits", "MiB", "RequestGuard", "RowId", "UploadTooLarge", "check_frame_id", "check_id",
           "check_model_spec", "check_name", "check_options", "check_zip", "cross_site_write", "extract_zip",
           "format_bytes", "install_redaction", "is_loopback", "is_loopback_host", "redact", "remove_tree",
           "safe_component", "token_dependency", "within"]
