"""Where a warehouse is: a local folder or an object-store prefix, and how to reach it.

:class:`Location` is a warehouse (or a folder inside it: ``loc / "tables" / name``) as a
URI plus the storage options that reach it. A local path (``/srv/surveil/warehouse``,
``warehouse``, ``file:///srv/wh``) behaves exactly as the ``Path`` it replaces, and is
one (``os.fspath(loc)``, ``Path(loc)``). ``s3://bucket/prefix`` is Amazon S3 or any
S3-compatible store (MinIO, Ceph, R2, ...): its data files, Delta logs, pending
markers, staging and records are objects under the prefix, read and written through
pyarrow's ``S3FileSystem`` (:attr:`Location.fs`), deltalake with
:attr:`Location.storage_options`, and DuckDB over pyarrow datasets on the same
filesystem object (``pipeline.warehouse.views.register_tables``). A local-only call on
it (``Path(loc)``) raises instead of silently making a folder named ``s3:`` in the
working directory, and any other scheme is refused (:func:`parse_location`, exit 2).

Storage options (credentials, endpoint, region) come from the process's environment
(``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``, ``AWS_SESSION_TOKEN``, ``AWS_REGION``
or ``AWS_DEFAULT_REGION``, ``AWS_ENDPOINT_URL`` / ``AWS_ENDPOINT_URL_S3``,
``AWS_ALLOW_HTTP``), then the config's ``[warehouse] storage_options`` over them (keys as
deltalake names them, any case: ``aws_endpoint_url``, ``aws_region``, ...). They are
resolved in each process that opens the warehouse (a Ray worker on another node reads
its own environment); only the config's travel with a work unit (pickled with it, as the
config is). Neither is ever printed: ``repr`` shows the URI only, ``surveil config
check`` masks the values. Without keys in either, pyarrow and deltalake use their own
credential chains (instance profile, ``~/.aws``).

Delta commits on S3 use conditional puts (``aws_conditional_put = "etag"``, the
default set here: Amazon S3, MinIO and R2 support ``If-None-Match``), so two writers
cannot both create a table's version N: see ``pipeline.warehouse.lock`` for what the
writer lock guarantees there.
"""

from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

from pipeline.config import is_secret_option
from pipeline.errors import UsageError

__all__ = ["Location", "as_location", "checked_warehouse", "is_secret_option",
           "parse_location", "refuse_pre_sites", "require_warehouse"]

# deltalake (1.6) panics on a table path with these ("Invalid object store url") or fails
# on a control character: refused up front, exit 2, instead of a Rust panic mid-commit
_DELTA_UNSAFE = frozenset("^[]|\\")

OBJECT_SCHEMES = ("s3",)  # s3a is read as s3
_ENV_OPTIONS = (  # (environment variable, storage option), in order of precedence
    ("AWS_ACCESS_KEY_ID", "aws_access_key_id"),
    ("AWS_SECRET_ACCESS_KEY", "aws_secret_access_key"),
    ("AWS_SESSION_TOKEN", "aws_session_token"),
    ("AWS_DEFAULT_REGION", "aws_region"),
    ("AWS_REGION", "aws_region"),
    ("AWS_ENDPOINT_URL", "aws_endpoint_url"),
    ("AWS_ENDPOINT_URL_S3", "aws_endpoint_url"),
    ("AWS_ALLOW_HTTP", "aws_allow_http"),
)
_ALIASES = {"aws_endpoint": "aws_endpoint_url", "endpoint_url": "aws_endpoint_url",
            "endpoint": "aws_endpoint_url", "region": "aws_region",
            "access_key_id": "aws_access_key_id", "secret_access_key": "aws_secret_access_key",
            "session_token": "aws_session_token", "allow_http": "aws_allow_http"}
def _normalised(options: Mapping[str, str]) -> dict[str, str]:
    out = {}
    for k, v in options.items():
        key = k.lower()
        out[_ALIASES.get(key, key)] = str(v)
    return out


class Location:
    """A warehouse or a folder of one: ``uri`` (a local path, or ``s3://bucket/key``) and
    the config's storage options (module docstring). Immutable, hashable, picklable (the
    filesystem is made again in the process that unpickles it)."""

    def __init__(self, uri: str | os.PathLike, options: Iterable[tuple[str, str]] = ()) -> None:
        object.__setattr__(self, "uri", str(uri))
        object.__setattr__(self, "_options", tuple(sorted(_normalised(dict(options)).items())))

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("a Location is immutable")

    def __reduce__(self) -> tuple[Any, ...]:
        return (Location, (self.uri, self._options))

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Location) and (self.uri, self._options)
                == (other.uri, other._options))

    def __hash__(self) -> int:
        return hash((self.uri, self._options))

    def __repr__(self) -> str:  # never the options: they may hold credentials
        return f"Location({self.uri!r})"

    def __str__(self) -> str:
        return self.uri

    def __fspath__(self) -> str:
        if not self.is_local:
            raise TypeError(f"{self.uri} is on object storage, not a local path: open it "
                            "through pipeline.warehouse.location.Location")
        return self.uri

    # - where -
    @functools.cached_property
    def scheme(self) -> str:
        """``""`` for a local path, else the URI's scheme (``s3``)."""
        head, sep, _ = self.uri.partition("://")
        return head.lower() if sep else ""

    @property
    def is_local(self) -> bool:
        return self.scheme == ""

    def __truediv__(self, part: str) -> Location:
        part = str(part).strip("/")
        if self.is_local:
            return Location(os.path.join(self.uri, part), self._options)
        return Location(f"{self.uri.rstrip('/')}/{part}", self._options)

    @property
    def name(self) -> str:
        return os.path.basename(self.uri.rstrip("/"))

    @property
    def parent(self) -> Location:
        if self.is_local:
            return Location(os.path.dirname(self.uri.rstrip("/")) or ".", self._options)
        head, _, _ = self.uri.rstrip("/").rpartition("/")
        return Location(head, self._options)

    def at(self, other: str | os.PathLike) -> Location:
        """Another file or folder on the same storage (the same options): a path or URI
        a manifest names (``StagedFile.path``)."""
        if isinstance(other, Location):
            return Location(other.uri, self._options)
        other = os.fspath(other) if isinstance(other, os.PathLike) else str(other)
        if "://" in other and other.split("://", 1)[0].lower() == "file":
            other = unquote(urlparse(other).path)
        return Location(other, self._options)

    @property
    def path(self) -> Path:
        """The local path (a :class:`TypeError` on object storage)."""
        return Path(os.fspath(self))

    @property
    def config_options(self) -> dict[str, str]:
        """The options given with the location (the config's), without the environment."""
        return dict(self._options)

    # - how to reach it -
    @functools.cached_property
    def storage_options(self) -> dict[str, str]:
        """deltalake's (and object_store's) ``storage_options`` in this process: the
        environment's, the config's over them; ``{}`` for a local path."""
        if self.is_local:
            return {}
        out: dict[str, str] = {}
        for env, key in _ENV_OPTIONS:
            if os.environ.get(env):
                out[key] = os.environ[env]
        out.update(self._options)
        endpoint = out.get("aws_endpoint_url", "")
        if endpoint.startswith("http://"):
            out.setdefault("aws_allow_http", "true")
        if "aws_s3_locking_provider" not in out:
            out.setdefault("aws_conditional_put", "etag")
        return out

    @functools.cached_property
    def fs(self) -> Any:
        """The pyarrow filesystem (``LocalFileSystem``, ``S3FileSystem``: one per set of
        storage options in a process, shared by every location that has them)."""
        import pyarrow.fs as pafs

        if self.is_local:
            return pafs.LocalFileSystem()
        return _s3_filesystem(tuple(sorted(self.storage_options.items())))

    @property
    def fs_path(self) -> str:
        """The path as :attr:`fs` names it (``bucket/key`` on S3, absolute locally)."""
        if self.is_local:
            return os.path.abspath(self.uri)
        return self.uri.split("://", 1)[1].rstrip("/")

    def fs_path_of(self, uri: str) -> str:
        """A file URI that deltalake lists (``s3://b/k``, ``file:///p``, a path with
        ``%``-escapes) as :attr:`fs` names it."""
        if "://" not in uri:
            return unquote(uri)
        scheme, rest = uri.split("://", 1)
        return unquote(rest) if scheme.lower() == "file" else unquote(rest).rstrip("/")

    # - files and folders (locally exactly the os calls the code made before) -
    def exists(self) -> bool:
        if self.is_local:
            return os.path.exists(self.uri)
        import pyarrow.fs as pafs

        return self.fs.get_file_info(self.fs_path).type != pafs.FileType.NotFound

    def is_dir(self) -> bool:
        """A folder (on object storage: a prefix holding at least one object)."""
        if self.is_local:
            return os.path.isdir(self.uri)
        return bool(self.listdir(missing_ok=True))

    def listdir(self, missing_ok: bool = False) -> list[str]:
        """Names directly under this folder (FileNotFoundError when it is not there,
        unless ``missing_ok``)."""
        if self.is_local:
            try:
                return os.listdir(self.uri)
            except (FileNotFoundError, NotADirectoryError):
                if missing_ok:
                    return []
                raise
        import pyarrow.fs as pafs

        base = self.fs_path + "/"
        infos = self.fs.get_file_info(pafs.FileSelector(base, allow_not_found=True))
        names = [i.path[len(base):] for i in infos if i.path.startswith(base)]
        if not names and not missing_ok:
            raise FileNotFoundError(self.uri)
        return names

    def stat(self) -> tuple[int, int]:
        """``(size_bytes, mtime_ns)`` (FileNotFoundError when absent). Object stores give
        the last-modified time in whole seconds."""
        if self.is_local:
            st = os.stat(self.uri)
            return st.st_size, st.st_mtime_ns
        import pyarrow.fs as pafs

        info = self.fs.get_file_info(self.fs_path)
        if info.type == pafs.FileType.NotFound:
            raise FileNotFoundError(self.uri)
        return int(info.size or 0), int(info.mtime_ns or 0)

    def read_bytes(self) -> bytes:
        if self.is_local:
            with open(self.uri, "rb") as f:
                return f.read()
        with self.fs.open_input_stream(self.fs_path) as f:
            return f.read()

    def read_text(self) -> str:
        return self.read_bytes().decode()

    def write_atomic(self, data: bytes) -> None:
        """Write the file whole or not at all: locally a temporary file then
        ``os.replace``; on object storage one PUT (an object appears whole)."""
        if self.is_local:
            tmp = self.uri + ".tmp"
            with open(tmp, "wb") as f:
                f.write(data)
            os.replace(tmp, self.uri)
            return
        with self.fs.open_output_stream(self.fs_path) as f:
            f.write(data)

    def mkdir(self, parents: bool = True, exist_ok: bool = True) -> None:
        """Make the folder and its parents (nothing on object storage: no folders)."""
        if self.is_local:
            os.makedirs(self.uri, exist_ok=True)

    def unlink(self) -> None:
        """Remove the file; nothing when it is not there."""
        if self.is_local:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.uri)
            return
        with contextlib.suppress(FileNotFoundError):
            self.fs.delete_file(self.fs_path)

    def rmtree(self) -> None:
        """Remove the folder and everything under it, ignoring errors."""
        if self.is_local:
            shutil.rmtree(self.uri, ignore_errors=True)
            return
        with contextlib.suppress(OSError):  # (pyarrow may leave empty "folder/" markers)
            self.fs.delete_dir(self.fs_path)

    def rmdir_if_empty(self) -> None:
        """Remove the folder when it is empty (object storage has no empty folders)."""
        if self.is_local:
            with contextlib.suppress(OSError):
                os.rmdir(self.uri)

    def move_to(self, target: Location) -> None:
        """Move a file: a rename locally (a copy across file systems), a server-side
        copy then delete on object storage."""
        if self.is_local and target.is_local:
            try:
                os.replace(self.uri, target.uri)
            except OSError:  # another file system: copy, then drop the source
                shutil.copyfile(self.uri, target.uri)
                os.remove(self.uri)
            return
        self.fs.move(self.fs_path, target.fs_path)

    def open_output(self) -> Any:
        """A pyarrow output stream writing this file (replaced if there)."""
        if self.is_local:
            import pyarrow as pa

            return pa.OSFile(self.uri, "wb")
        return self.fs.open_output_stream(self.fs_path)

    def open_input(self) -> Any:
        """A pyarrow random-access file reading this file (memory-mapped locally)."""
        if self.is_local:
            import pyarrow as pa

            return pa.memory_map(self.uri)
        return self.fs.open_input_file(self.fs_path)


@functools.lru_cache(maxsize=8)
def _s3_filesystem(options: tuple[tuple[str, str], ...]) -> Any:
    """pyarrow's ``S3FileSystem`` for resolved storage options (made once per process:
    it holds the AWS SDK's client and its connection pool)."""
    import pyarrow.fs as pafs

    o = dict(options)
    kw: dict[str, Any] = {}
    if "aws_access_key_id" in o:
        kw.update(access_key=o["aws_access_key_id"], secret_key=o.get("aws_secret_access_key", ""))
        if "aws_session_token" in o:
            kw["session_token"] = o["aws_session_token"]
    if "aws_region" in o:
        kw["region"] = o["aws_region"]
    endpoint = o.get("aws_endpoint_url")
    if endpoint:
        parsed = urlparse(endpoint)
        kw["endpoint_override"] = parsed.netloc or parsed.path
        kw["scheme"] = parsed.scheme or "https"
    return pafs.S3FileSystem(**kw)


def parse_location(text: str | os.PathLike | Location,
                   options: Mapping[str, str] | None = None) -> Location:
    """A warehouse given on the command line or in the config -> :class:`Location`.
    ``file://`` URIs and plain paths are local; ``s3://`` (and ``s3a://``) object
    storage; any other scheme is a :class:`UsageError` (exit 2), never a folder named
    ``scheme:``."""
    if isinstance(text, Location):
        return text if options is None else Location(text.uri, options.items())
    raw = os.fspath(text) if isinstance(text, os.PathLike) else str(text)
    opts = tuple((options or {}).items())
    head, sep, rest = raw.partition("://")
    if not sep:
        return Location(raw, opts)
    scheme = head.lower()
    if scheme == "file":
        return Location(unquote(urlparse(raw).path), opts)
    if scheme in ("s3", "s3a"):
        bucket = rest.split("/", 1)[0]
        if not bucket:
            raise UsageError(f"warehouse {raw!r} names no bucket: use s3://BUCKET/PREFIX")
        if importlib.util.find_spec("obstore") is None:  # the lease lock's conditional puts
            raise UsageError(f"warehouse {raw!r} is on object storage, which needs obstore: "
                             "pip install 'surveil-pipeline[s3]'")
        return Location(f"s3://{rest.rstrip('/')}", opts)
    raise UsageError(
        f"warehouse {raw!r}: unknown scheme {head!r}; a warehouse is a local folder, "
        "file://PATH or s3://BUCKET/PREFIX (S3 or an S3-compatible store)")


def as_location(warehouse: str | os.PathLike | Location) -> Location:
    """``warehouse`` as a :class:`Location` (a ``Path`` or a string as it is today)."""
    return warehouse if isinstance(warehouse, Location) else parse_location(warehouse)


def checked_warehouse(path: Path | str | Location,
                      options: Mapping[str, str] | None = None) -> Location:
    """The warehouse, absolute when local; :class:`UsageError` when Delta cannot use
    its path (or its scheme is unknown)."""
    loc = parse_location(path, options)
    if loc.is_local:
        loc = Location(str(Path(loc.uri).expanduser().resolve()), loc.config_options.items())
    bad = sorted({c for c in loc.uri.split("://")[-1] if c in _DELTA_UNSAFE or ord(c) < 32})
    if bad:
        raise UsageError(
            f"warehouse path {loc.uri!r} holds {', '.join(repr(c) for c in bad)}, which the "
            "Delta Lake library cannot use in a table path: choose another directory"
        )
    if loc.is_local and "," in loc.uri:  # DuckDB's file_search_path is a comma list
        raise UsageError(f"warehouse path {loc.uri!r} holds ',', which the views file "
                         "(DuckDB's file_search_path, a comma-separated list) cannot name: "
                         "choose another directory")
    return loc


def require_warehouse(warehouse: Path | Location) -> Location:
    """``warehouse`` when it is one (a folder holding ``tables/``, what ``ingest``, ``run``
    and ``demo`` create), else :class:`UsageError` naming it: a command that reads a
    warehouse must not read a mistyped path as an empty one, nor create it."""
    loc = as_location(warehouse)
    if not (loc / "tables").is_dir():
        why = "does not exist" if not loc.exists() else "is not a warehouse (no tables/ in it)"
        raise UsageError(
            f"warehouse {loc} {why}; `surveil ingest ARCHIVE --warehouse {loc}` (or "
            "`surveil run`, `surveil demo`) creates one")
    return loc


def refuse_pre_sites(warehouse: Path | Location) -> None:
    """:class:`UsageError` when ``warehouse`` was written before rows carried their site
    (its ``ingest_ledger`` has no ``site`` column): ids of two sites could not be told
    apart in it, so it is not migrated in place; rebuild it from the archive."""
    loc = as_location(warehouse)
    table = loc / "tables" / "ingest_ledger"
    if not (table / "_delta_log").is_dir():
        return
    from deltalake import DeltaTable
    from deltalake.exceptions import DeltaError

    try:
        dt = DeltaTable(table.uri, storage_options=table.storage_options or None)
    except DeltaError:  # a damaged ledger: the command that reads it says so (exit 2)
        return
    names = {f.name for f in dt.schema().fields}
    if "site" not in names:
        raise UsageError(
            f"warehouse {loc} was written before rows carried their site (no `site` "
            "column); rebuild it: `surveil ingest ARCHIVE --warehouse NEW [--site NAME]` "
            "then `surveil batch` (docs/operations.md, 'Many sites, one warehouse')")
