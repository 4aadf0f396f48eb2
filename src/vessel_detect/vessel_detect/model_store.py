"""Find, download and verify the detector's ONNX model.

A model is named by a file path, or by a URL plus its sha256. Search order for the file:

1. the explicit ``model_path`` parameter;
2. the ``VESSEL_MODEL`` environment variable;
3. the shared development copy ``<repo>/../shared/models/yolox_nano/<file name>`` (accepted only when its
   checksum is the expected one);
4. the download cache (``VESSEL_MODEL_CACHE`` or ``~/.cache/vessel_tracking/models``), file named after the
   URL, checksum verified;
5. a download from ``model_url`` into the cache (urllib; written to a temporary file, verified, then renamed,
   so the cache never holds a partial or wrong file).

onnxruntime runs whatever graph a model file holds, so nothing is downloaded unchecked: only over https (a
redirect to anything else is refused), and only with the sha256 the file must have (``model_sha256``; the default
model's is built in). A local file is given as ``model_path``, not as a ``file://`` URL.

Anything missing or corrupt raises :class:`ModelError` naming the file, the expected checksum and how to get
the model (into the cache folder actually used).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path

from vessel_common.errors import ModelError
from vessel_common.paths import in_repo

DEFAULT_MODEL_FILENAME = "yolox_nano.onnx"
DEFAULT_MODEL_SHA256 = "695e750a5d5754bb5a8d5325643b59282191a7e7a564e435a415fd3c578eab14"
DEFAULT_MODEL_URL = "https://github.com/Kazuhito00/YOLOX-ONNX-TFLite-Sample/raw/HEAD/model/yolox_nano.onnx"
DEFAULT_MODEL_SOURCE = (
    "YOLOX-Nano (COCO, Apache-2.0) from the repository Kazuhito00/YOLOX-ONNX-TFLite-Sample, model/yolox_nano.onnx"
)

MODEL_ENV = "VESSEL_MODEL"
CACHE_ENV = "VESSEL_MODEL_CACHE"
SHARED_MODEL_SUBDIR = Path("shared") / "models" / "yolox_nano"
DOWNLOAD_TIMEOUT_S = 60.0
_SHA256 = re.compile(r"[0-9a-f]{64}")


@dataclass(frozen=True)
class ModelSpec:
    """Which model to use, as given in the parameters.

    Attributes:
        path: explicit file path ('' to search).
        url: where to download it from ('' for the default model's URL when no path is given).
        sha256: expected checksum, lowercase hex ('' for: the default model's when neither path nor url is
            given or the url is the default model's, unchecked for an explicit path; a url needs one).

    """

    path: str = ""
    url: str = ""
    sha256: str = ""

    @property
    def is_default_model(self) -> bool:
        """Neither a path nor a URL was given: the project's default YOLOX-Nano."""
        return not self.path and not self.url

    @property
    def expected_sha256(self) -> str:
        """The checksum the file must have ('' when none is required)."""
        if self.sha256.strip():
            return self.sha256.strip().lower()
        return DEFAULT_MODEL_SHA256 if self.is_default_model or self.url.strip() == DEFAULT_MODEL_URL else ""

    @property
    def effective_url(self) -> str:
        """The URL to download from ('' when there is none)."""
        if self.url:
            return self.url
        return DEFAULT_MODEL_URL if self.is_default_model else ""

    @property
    def file_name(self) -> str:
        """The model's file name (from the path, the URL, or the default)."""
        if self.path:
            return Path(self.path).name
        url = self.effective_url
        name = Path(urllib.parse.urlparse(url).path).name if url else ""
        return name or DEFAULT_MODEL_FILENAME


def sha256_of(path: Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def repo_root() -> Path:
    """The project's repository root (the folder holding ``src/vessel_detect``), or this file's best guess."""
    try:
        from vessel_common.paths import repo_root as dataset_repo_root

        return Path(dataset_repo_root())
    except (ImportError, AttributeError):
        pass
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "src" / "vessel_detect").is_dir():
            return parent
    return here.parents[3]


def default_cache_dir() -> Path:
    """Where downloaded models go: ``$VESSEL_MODEL_CACHE`` or ``~/.cache/vessel_tracking/models``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "vessel_tracking" / "models"


def shared_model_dir() -> Path:
    """The development copy of the default model next to the repository (``<repo>/../shared/models/...``)."""
    return repo_root().parent / SHARED_MODEL_SUBDIR


def how_to_get(spec: ModelSpec, cache_dir: Path | None = None) -> str:
    """One sentence on how to obtain the model the spec names (into ``cache_dir``, None: the default cache)."""
    cache = (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / spec.file_name
    checksum = f" (sha256 {spec.expected_sha256})" if spec.expected_sha256 else ""
    if spec.is_default_model:
        return (
            f"get the default model, {DEFAULT_MODEL_SOURCE}{checksum}: download {DEFAULT_MODEL_URL} to {cache}, "
            f"or set model_path (or ${MODEL_ENV}) to a copy of it"
        )
    if spec.url:
        return f"download {spec.url}{checksum} to {cache}, or set model_path to a local copy"
    return (
        "set model_path to an existing ONNX model file, or leave model_path and model_url empty to use the "
        f"default YOLOX-Nano (from ../shared/models, the cache, or {DEFAULT_MODEL_URL})"
    )


def check_download_source(spec: ModelSpec) -> None:
    """ModelError unless what ``spec`` would download is checked: an https URL, with a sha256 (64 hex digits).

    A model is run by onnxruntime, so a file fetched over plain HTTP, or run without a known checksum, is whatever
    the network path served. A ``model_path`` needs no URL (a local file; ``model_sha256`` then checks it if given).
    """
    if spec.sha256.strip() and not _SHA256.fullmatch(spec.expected_sha256):
        raise ModelError(f"model_sha256 {spec.sha256!r} is not a sha256 (64 hex digits): give model_sha256:=<sha256 "
                         "of the file> (what `sha256sum FILE` prints)")
    url = spec.effective_url
    if spec.path or not url:
        return
    scheme = urllib.parse.urlparse(url).scheme.lower()
    if scheme == "file":
        local = urllib.request.url2pathname(urllib.parse.urlparse(url).path)
        raise ModelError(f"model_url {url} is a local file: use model_path for a local file (model_path:={local}, "
                         "with model_sha256 to check it), and leave model_url empty")
    if scheme != "https":
        raise ModelError(f"model_url {url} is not https: models are downloaded only over https (a plain download "
                         "can be changed on its way); give the https URL, or use model_path for a local file")
    if not spec.expected_sha256:
        raise ModelError(f"model_url {url} is given without model_sha256: a downloaded model is used only when its "
                         "checksum is known; give model_sha256:=<sha256 of the file>, or use model_path for a "
                         "local file")


class _HttpsOnlyRedirects(urllib.request.HTTPRedirectHandler):
    """Follow a redirect only to another https URL (a download must not leave https on its way)."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        if urllib.parse.urlparse(newurl).scheme.lower() != "https":
            raise urllib.error.URLError(f"redirected to {newurl}, which is not https")
        return super().redirect_request(req, fp, code, msg, headers, newurl)


def _open_url(url: str, timeout_s: float):
    """The response of an https GET of ``url`` whose redirects stay on https (the test suite replaces this)."""
    opener = urllib.request.build_opener(_HttpsOnlyRedirects())
    return opener.open(url, timeout=timeout_s)


def _verify(path: Path, spec: ModelSpec, what: str, cache_dir: Path | None = None) -> None:
    expected = spec.expected_sha256
    if not expected:
        return
    actual = sha256_of(path)
    if actual != expected:
        raise ModelError(
            f"{what} {path} has sha256 {actual}, expected {expected}: the file is corrupt or a different "
            f"model; {how_to_get(spec, cache_dir)} (or set model_sha256 to the checksum of the model you mean to use)"
        )


def _checksum_matches(path: Path, spec: ModelSpec) -> bool:
    expected = spec.expected_sha256
    return not expected or sha256_of(path) == expected


def download(url: str, destination: Path, spec: ModelSpec, timeout_s: float = DOWNLOAD_TIMEOUT_S) -> Path:
    """Download ``url`` to ``destination`` atomically, verifying the checksum before the rename.

    ModelError, before anything is fetched, for a URL that is not https or a spec without a sha256.
    """
    check_download_source(ModelSpec(url=url, sha256=spec.expected_sha256))
    destination.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = tempfile.mkstemp(prefix=f".{destination.name}.", suffix=".part", dir=destination.parent)
    temp_path = Path(temp_name)
    try:
        with os.fdopen(handle, "wb") as out:
            try:
                with _open_url(url, timeout_s) as response:
                    while True:
                        block = response.read(1 << 20)
                        if not block:
                            break
                        out.write(block)
            except (urllib.error.URLError, OSError, ValueError) as error:
                reason = getattr(error, "reason", error)
                raise ModelError(
                    f"cannot download the model from {url}: {reason}; {how_to_get(spec, destination.parent)}"
                ) from None
        _verify(temp_path, spec, f"the model downloaded from {url} to", destination.parent)
        os.replace(temp_path, destination)
    finally:
        if temp_path.exists():
            temp_path.unlink()
    return destination


def resolve_model(
    spec: ModelSpec,
    cache_dir: Path | None = None,
    allow_download: bool = True,
    search_shared: bool = True,
) -> Path:
    """Return the path of a verified model file, downloading it into the cache if needed.

    Raises:
        ModelError: the named file is missing or its checksum is wrong, or nothing was found and the
            download failed or is not allowed; the message names the file(s), the checksum and the fix. Also,
            before anything is looked for, a model_url that is not https or comes without model_sha256.

    """
    check_download_source(spec)
    cache_dir = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    if spec.path:
        path = Path(spec.path).expanduser()
        if in_repo(path).is_file():
            path = in_repo(path)  # found here, or a model shipped in the repository, named from its root
        if not path.is_file():
            raise ModelError(f"model file {path} (model_path) not found; {how_to_get(spec, cache_dir)}")
        _verify(path, spec, "model file", cache_dir)
        return path
    env_path = os.environ.get(MODEL_ENV)
    if env_path:
        path = Path(env_path).expanduser()
        if not path.is_file():
            raise ModelError(f"model file {path} (from ${MODEL_ENV}) not found; {how_to_get(spec, cache_dir)}")
        _verify(path, spec, f"model file (${MODEL_ENV})", cache_dir)
        return path
    searched = []
    if search_shared:
        shared = shared_model_dir() / spec.file_name
        searched.append(str(shared))
        if shared.is_file() and _checksum_matches(shared, spec):
            return shared
    cached = cache_dir / spec.file_name
    searched.append(str(cached))
    if cached.is_file():
        if _checksum_matches(cached, spec):
            return cached
        if not (allow_download and spec.effective_url):
            _verify(cached, spec, "cached model", cache_dir)
    url = spec.effective_url
    if not url or not allow_download:
        reason = "no model_url to download it from" if not url else "downloads are disabled"
        raise ModelError(
            f"model {spec.file_name} not found (looked in: {', '.join(searched)}) and {reason}; "
            f"{how_to_get(spec, cache_dir)}"
        )
    return download(url, cached, spec)
