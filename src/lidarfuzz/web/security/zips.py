"""Uploaded zips: every member checked before anything is extracted — absolute paths, ``..``,
links and special files, member count and total uncompressed size — and every write counted
against the limits again while extracting."""

from __future__ import annotations

import re
import stat
import zipfile
from pathlib import Path, PurePosixPath

from fastapi import HTTPException, status

from lidarfuzz.web.security.limits import Limits, MiB, format_bytes
from lidarfuzz.web.security.paths import safe_component, within

# parts of a zip that are not data: macOS resource forks and Finder files
IGNORED_MEMBERS = ("__MACOSX/",)


def _bad_member(name: str, why: str) -> HTTPException:
    return HTTPException(status.HTTP_400_BAD_REQUEST, f"{name}: {why}; nothing was extracted")


def check_zip(archive: zipfile.ZipFile, limits: Limits) -> list[tuple[zipfile.ZipInfo, PurePosixPath]]:
    """Every member that will be extracted, with its sanitised relative path; raises 400 naming
    the first member that is absolute, climbs out with ``..``, is a link or special file, or
    breaks the count / size limits. Nothing is written."""
    infos = archive.infolist()
    if len(infos) > limits.max_members:
        raise _bad_member(infos[limits.max_members].filename,
                          f"the zip has {len(infos)} members, more than the limit of {limits.max_members}")
    chosen: list[tuple[zipfile.ZipInfo, PurePosixPath]] = []
    total = 0
    for info in infos:
        name = info.filename
        if "\x00" in name:
            raise _bad_member(repr(name), "a member name with a NUL byte")
        posix = name.replace("\\", "/")
        if posix.startswith("/") or re.match(r"^[A-Za-z]:", posix):
            raise _bad_member(name, "an absolute path")
        parts = [p for p in posix.split("/") if p not in ("", ".")]
        if ".." in parts:
            raise _bad_member(name, "a path with '..' (zip-slip)")
        kind = stat.S_IFMT(info.external_attr >> 16) if info.create_system == 3 else 0  # Unix file type bits
        if kind and kind not in (stat.S_IFREG, stat.S_IFDIR):
            raise _bad_member(name, "a symbolic link" if kind == stat.S_IFLNK else "not a regular file")
        total += info.file_size
        if total > limits.max_unzipped:
            raise _bad_member(name, f"the zip unpacks to more than the limit of {format_bytes(limits.max_unzipped)}")
        if info.is_dir() or not parts or posix.startswith(IGNORED_MEMBERS) or parts[-1].startswith("."):
            continue
        chosen.append((info, PurePosixPath(*(safe_component(p) for p in parts))))
    seen: dict[PurePosixPath, str] = {}
    for info, rel in chosen:
        if rel in seen:
            raise _bad_member(info.filename, f"has the same sanitised name as {seen[rel]!r}")
        seen[rel] = info.filename
    return chosen


def extract_zip(path: Path, dest: Path, limits: Limits) -> list[Path]:
    """Extract a zip into ``dest`` after :func:`check_zip`; every write is counted against the
    limits again (a member may unpack to more than its header says)."""
    try:
        archive = zipfile.ZipFile(path)
    except zipfile.BadZipFile as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{path.name}: not a zip file ({exc})") from None
    written: list[Path] = []
    with archive:
        members = check_zip(archive, limits)
        total = 0
        for info, rel in members:
            target = dest.joinpath(*rel.parts)
            if not within(target, dest):  # unreachable after check_zip; kept as the last line of defence
                raise _bad_member(info.filename, "outside the upload folder")
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with archive.open(info) as source, target.open("xb") as out:
                    while chunk := source.read(MiB):
                        total += len(chunk)
                        if total > limits.max_unzipped:
                            raise _bad_member(info.filename, f"the zip unpacks to more than the limit of "
                                                             f"{format_bytes(limits.max_unzipped)}")
                        out.write(chunk)
            except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError) as exc:
                raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{info.filename}: cannot extract ({exc})") from None
            written.append(target)
    return written


__all__ = ["check_zip", "extract_zip"]
