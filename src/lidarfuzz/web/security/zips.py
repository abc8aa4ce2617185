"""Uploaded zips: every member checked before anything is extracted — absolute paths, ``..``,
over-deep or over-long paths, links and special files, encrypted members, members whose data
overlap (a zip bomb's shared kernel), member count, and the sizes and compression ratios the
headers declare — and then every byte counted while extracting, never trusting a header: a
member stops when it unpacks to more than it declared, to more than ``max_ratio`` times its
compressed size, or when the whole zip passes ``max_unzipped`` or ``max_ratio`` times its size.
Nothing is left behind on a refusal (the caller removes the upload's folder)."""

from __future__ import annotations

import itertools
import lzma
import re
import stat
import zipfile
import zlib
from pathlib import Path, PurePosixPath

from fastapi import HTTPException, status

from lidarfuzz.web.security.limits import Limits, MiB, format_bytes
from lidarfuzz.web.security.paths import safe_component, within

# parts of a zip that are not data: macOS resource forks and Finder files
IGNORED_MEMBERS = ("__MACOSX/",)
#: The fixed part of a zip's local file header (its name and extra field follow)
LOCAL_HEADER = 30
#: The longest folder or file name most file systems keep
MAX_COMPONENT = 255
#: What a member can raise while it is read: a corrupt stream, an unknown method, a password
EXTRACT_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, zlib.error, lzma.LZMAError,
                  NotImplementedError, RuntimeError, ValueError)


def _shown(name: str) -> str:
    """A member's name for a message: as it is, or quoted with escapes when it holds control characters."""
    return repr(name) if any(ord(c) < 32 or 127 <= ord(c) < 160 for c in name) else name


def _bad_member(name: str, why: str) -> HTTPException:
    return HTTPException(status.HTTP_400_BAD_REQUEST, f"{_shown(name)}: {why}; nothing was extracted")


def _ratio_limit(compressed: int, limits: Limits) -> int:
    """The most bytes ``compressed`` bytes may unpack to."""
    return max(limits.ratio_grace, compressed * limits.max_ratio)


def _check_path(info: zipfile.ZipInfo, limits: Limits) -> list[str]:
    """The member's path parts; raises naming it when its path is absolute, climbs out, is too deep or too long."""
    name = info.filename
    if "\x00" in name:
        raise _bad_member(name, "a member name with a NUL byte")
    posix = name.replace("\\", "/")
    if posix.startswith("/") or re.match(r"^[A-Za-z]:", posix):
        raise _bad_member(name, "an absolute path")
    parts = [p for p in posix.split("/") if p not in ("", ".")]
    if ".." in parts:
        raise _bad_member(name, "a path with '..' (zip-slip)")
    if len(name) > limits.max_name or any(len(p) > MAX_COMPONENT for p in parts):
        raise _bad_member(name[:80] + "...", f"a path longer than {limits.max_name} characters, or a name in it "
                                             f"longer than {MAX_COMPONENT}")
    folders = len(parts) - (0 if info.is_dir() else 1)
    if folders > limits.max_depth:
        raise _bad_member(name, f"{folders} folders deep, more than the limit of {limits.max_depth}")
    return parts


def _check_kind(info: zipfile.ZipInfo) -> None:
    """Refuse links, special files and encrypted members."""
    kind = stat.S_IFMT(info.external_attr >> 16) if info.create_system == 3 else 0  # Unix file type bits
    if kind and kind not in (stat.S_IFREG, stat.S_IFDIR):
        raise _bad_member(info.filename, "a symbolic link" if kind == stat.S_IFLNK else "not a regular file")
    if info.flag_bits & 0x1:
        raise _bad_member(info.filename, "an encrypted member")


def _check_overlap(infos: list[zipfile.ZipInfo]) -> None:
    """Refuse members whose data overlap another's: the trick of zip bombs that unpack one
    compressed kernel many times (each member's header offset must lie past the previous one's data)."""
    ordered = sorted(infos, key=lambda i: i.header_offset)
    for before, after in itertools.pairwise(ordered):
        end = before.header_offset + LOCAL_HEADER + before.compress_size  # its name and extra field only add to it
        if after.header_offset < end:
            raise _bad_member(after.filename, f"its data overlap those of {_shown(before.filename)!r} "
                                              "(a zip bomb)")


def check_zip(archive: zipfile.ZipFile, limits: Limits,
              archive_size: int | None = None) -> list[tuple[zipfile.ZipInfo, PurePosixPath]]:
    """Every member that will be extracted, with its sanitised relative path; raises 400 naming
    the first member that is absolute, climbs out with ``..``, is too deep or too long, is a link,
    special file or encrypted, overlaps another, or whose declared size breaks the count, size
    or ratio limits (``archive_size``: the zip's bytes, for the overall ratio). Nothing is written."""
    infos = archive.infolist()
    if len(infos) > limits.max_members:
        raise _bad_member(infos[limits.max_members].filename,
                          f"the zip has {len(infos)} members, more than the limit of {limits.max_members}")
    _check_overlap(infos)
    chosen: list[tuple[zipfile.ZipInfo, PurePosixPath]] = []
    total = 0
    for info in infos:
        name = info.filename
        parts = _check_path(info, limits)
        _check_kind(info)
        if info.file_size > _ratio_limit(info.compress_size, limits):
            raise _bad_member(name, f"declares {format_bytes(info.file_size)} from {format_bytes(info.compress_size)}"
                                    f", more than {limits.max_ratio} times its compressed size (a zip bomb)")
        total += info.file_size
        if total > limits.max_unzipped:
            raise _bad_member(name, f"the zip unpacks to more than the limit of {format_bytes(limits.max_unzipped)}")
        if archive_size is not None and total > _ratio_limit(archive_size, limits):
            raise _bad_member(name, f"the zip unpacks to more than {limits.max_ratio} times its size (a zip bomb)")
        if info.is_dir() or not parts or name.replace("\\", "/").startswith(IGNORED_MEMBERS) or \
                parts[-1].startswith("."):
            continue
        chosen.append((info, PurePosixPath(*(safe_component(p) for p in parts))))
    seen: dict[PurePosixPath, str] = {}
    for info, rel in chosen:
        if rel in seen:
            raise _bad_member(info.filename, f"has the same sanitised name as {seen[rel]!r}")
        seen[rel] = info.filename
    return chosen


class _Budget:
    """The bytes a zip may still unpack to, counted as they are written."""

    def __init__(self, limits: Limits, archive_size: int) -> None:
        self.limits = limits
        self.total = 0
        self.cap = min(limits.max_unzipped, _ratio_limit(archive_size, limits))

    def spend(self, info: zipfile.ZipInfo, written: int, chunk: int) -> None:
        """Count ``chunk`` more bytes of ``info`` (``written`` before them); raise on the first limit passed."""
        self.total += chunk
        member = written + chunk
        if member > info.file_size:
            raise _bad_member(info.filename, f"unpacks to more than the {format_bytes(info.file_size)} its header "
                                             "declares")
        if member > _ratio_limit(info.compress_size, self.limits):
            raise _bad_member(info.filename, f"unpacks to more than {self.limits.max_ratio} times its compressed "
                                             "size (a zip bomb)")
        if self.total > self.cap:
            limit = format_bytes(self.cap) if self.cap == self.limits.max_unzipped else \
                f"{self.limits.max_ratio} times its size"
            raise _bad_member(info.filename, f"the zip unpacks to more than the limit of {limit}")


def extract_zip(path: Path, dest: Path, limits: Limits) -> list[Path]:
    """Extract a zip into ``dest`` after :func:`check_zip`; every byte written is counted against
    the limits again (a header may lie about a member's size). On a refusal the files written so
    far stay in ``dest``: the caller removes the upload's folder."""
    size = path.stat().st_size
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError, NotImplementedError) as exc:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{path.name}: not a zip file ({exc})") from None
    written: list[Path] = []
    with archive:
        members = check_zip(archive, limits, size)
        budget = _Budget(limits, size)
        for info, rel in members:
            target = dest.joinpath(*rel.parts)
            if not within(target, dest):  # unreachable after check_zip; kept as the last line of defence
                raise _bad_member(info.filename, "outside the upload folder")
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                with archive.open(info) as source, target.open("xb") as out:
                    done = 0
                    while chunk := source.read(MiB):
                        budget.spend(info, done, len(chunk))
                        done += len(chunk)
                        out.write(chunk)
            except EXTRACT_ERRORS as exc:
                raise HTTPException(status.HTTP_400_BAD_REQUEST,
                                    f"{_shown(info.filename)}: cannot extract ({exc})") from None
            written.append(target)
    return written


__all__ = ["check_zip", "extract_zip"]
