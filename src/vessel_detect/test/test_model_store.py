"""Finding, downloading and verifying the model: missing files, checksum mismatches, https-only checked downloads."""

import hashlib
import io
import os
import urllib.error
import urllib.request

import pytest

from vessel_common.errors import ModelError
from vessel_detect import model_store
from vessel_detect.model_store import ModelSpec, resolve_model

CONTENT = b"pretend onnx bytes"
CONTENT_SHA = hashlib.sha256(CONTENT).hexdigest()


@pytest.fixture(autouse=True)
def no_env(monkeypatch):
    monkeypatch.delenv(model_store.MODEL_ENV, raising=False)
    monkeypatch.delenv(model_store.CACHE_ENV, raising=False)


class Served:
    """The network as ``model_store`` reaches it (``_open_url``): ``files`` URL -> bytes; ``fetched``: URLs asked."""

    def __init__(self):
        self.files: dict[str, bytes] = {}
        self.fetched: list[str] = []

    def open(self, url, timeout_s):
        self.fetched.append(url)
        if url not in self.files:
            raise urllib.error.URLError("404 Not Found")
        return io.BytesIO(self.files[url])


@pytest.fixture
def served(monkeypatch):
    network = Served()
    monkeypatch.setattr(model_store, "_open_url", network.open, raising=False)
    monkeypatch.setattr(urllib.request, "urlopen", lambda url, timeout=None: network.open(url, timeout))  # no network
    return network


URL = "https://models.example.org/v1/model.onnx"


def test_explicit_path_with_matching_checksum(tmp_path):
    path = tmp_path / "m.onnx"
    path.write_bytes(CONTENT)
    assert resolve_model(ModelSpec(path=str(path), sha256=CONTENT_SHA)) == path
    assert resolve_model(ModelSpec(path=str(path))) == path  # no checksum asked for


def test_missing_explicit_file_names_the_file(tmp_path):
    missing = tmp_path / "nope.onnx"
    with pytest.raises(ModelError, match="nope.onnx.*not found") as info:
        resolve_model(ModelSpec(path=str(missing)))
    assert "model_path" in str(info.value)


def test_checksum_mismatch_names_file_and_both_checksums(tmp_path):
    path = tmp_path / "m.onnx"
    path.write_bytes(CONTENT + b"corrupted")
    with pytest.raises(ModelError) as info:
        resolve_model(ModelSpec(path=str(path), sha256=CONTENT_SHA))
    message = str(info.value)
    assert str(path) in message and CONTENT_SHA in message
    assert hashlib.sha256(CONTENT + b"corrupted").hexdigest() in message


def test_env_variable_is_used(tmp_path, monkeypatch):
    path = tmp_path / "env.onnx"
    path.write_bytes(CONTENT)
    monkeypatch.setenv(model_store.MODEL_ENV, str(path))
    assert resolve_model(ModelSpec(sha256=CONTENT_SHA)) == path
    monkeypatch.setenv(model_store.MODEL_ENV, str(tmp_path / "gone.onnx"))
    with pytest.raises(ModelError, match="VESSEL_MODEL"):
        resolve_model(ModelSpec())


def test_https_download_into_the_cache_verified(tmp_path, served):
    served.files[URL] = CONTENT
    cache = tmp_path / "cache"
    spec = ModelSpec(url=URL, sha256=CONTENT_SHA)
    path = resolve_model(spec, cache_dir=cache, search_shared=False)
    assert path == cache / "model.onnx" and path.read_bytes() == CONTENT
    del served.files[URL]  # second time: from the cache, no download
    assert resolve_model(spec, cache_dir=cache, search_shared=False) == path and served.fetched == [URL]


def test_a_download_with_the_wrong_checksum_leaves_nothing_in_the_cache(tmp_path, served):
    served.files[URL] = CONTENT
    cache = tmp_path / "cache"
    spec = ModelSpec(url=URL, sha256="0" * 64)
    with pytest.raises(ModelError, match="0{64}") as info:
        resolve_model(spec, cache_dir=cache, search_shared=False)
    assert not any(cache.iterdir())
    assert f"to {cache / 'model.onnx'}" in str(info.value)  # the hint names the cache in use


def test_a_corrupt_cached_file_is_downloaded_again(tmp_path, served):
    served.files[URL] = CONTENT
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "model.onnx").write_bytes(b"half a file")
    path = resolve_model(ModelSpec(url=URL, sha256=CONTENT_SHA), cache_dir=cache, search_shared=False)
    assert path.read_bytes() == CONTENT


def test_unreachable_url_and_disabled_download_say_how_to_get_the_model_into_the_given_cache(tmp_path, served):
    spec = ModelSpec(url=URL, sha256=CONTENT_SHA)
    cache = tmp_path / "cache"
    with pytest.raises(ModelError, match="cannot download") as info:
        resolve_model(spec, cache_dir=cache, search_shared=False)
    assert CONTENT_SHA in str(info.value)
    with pytest.raises(ModelError, match="downloads are disabled") as disabled:
        resolve_model(spec, cache_dir=cache, allow_download=False, search_shared=False)
    assert not list(cache.glob("*.part"))
    for error in (info.value, disabled.value):
        assert f"download {URL} (sha256 {CONTENT_SHA}) to {cache / 'model.onnx'}" in str(error)
        assert str(model_store.default_cache_dir()) not in str(error)  # not ~/.cache when another cache is given


@pytest.mark.parametrize("url, sha256, refusal", [
    ("http://models.example.org/model.onnx", CONTENT_SHA, "is not https: models are downloaded only over https"),
    ("ftp://models.example.org/model.onnx", CONTENT_SHA, "is not https"),
    (URL, "", "is given without model_sha256: a downloaded model is used only when its checksum is known; give "
              "model_sha256:=<sha256 of the file>, or use model_path for a local file"),
    ("http://models.example.org/model.onnx", "", "is not https"),
    ("file:///srv/models/model.onnx", CONTENT_SHA, "is a local file: use model_path for a local file "
                                                   "(model_path:=/srv/models/model.onnx"),
    (URL, "not-a-checksum", "model_sha256 'not-a-checksum' is not a sha256 (64 hex digits): give "
                            "model_sha256:=<sha256 of the file>"),
], ids=["http", "ftp", "https-without-sha256", "http-without-sha256", "file-url", "not-a-sha256"])
def test_a_download_that_cannot_be_checked_is_refused_before_anything_is_fetched(tmp_path, served, url, sha256,
                                                                                  refusal):
    """A model_url without model_sha256 was downloaded over plain HTTP (or file://) and run with no check."""
    served.files[url] = CONTENT
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "model.onnx").write_bytes(b"whatever an earlier download left")  # not used unchecked either
    with pytest.raises(ModelError) as info:
        resolve_model(ModelSpec(url=url, sha256=sha256), cache_dir=cache, search_shared=False)
    assert str(info.value).startswith(f"model_url {url} " if "model_sha256 '" not in refusal else "model_sha256")
    assert refusal in str(info.value) and "\n" not in str(info.value)
    assert served.fetched == []
    with pytest.raises(ModelError, match="not https|without model_sha256|local file|not a sha256"):
        model_store.download(url, cache / "direct.onnx", ModelSpec(url=url, sha256=sha256))
    assert served.fetched == [] and sorted(p.name for p in cache.iterdir()) == ["model.onnx"]


def test_the_default_model_is_downloaded_with_its_built_in_checksum(tmp_path, served):
    served.files[model_store.DEFAULT_MODEL_URL] = b"not the model"
    cache = tmp_path / "cache"
    for spec in (ModelSpec(), ModelSpec(url=model_store.DEFAULT_MODEL_URL)):
        assert spec.expected_sha256 == model_store.DEFAULT_MODEL_SHA256
        model_store.check_download_source(spec)  # https and a known checksum: allowed
        with pytest.raises(ModelError, match=model_store.DEFAULT_MODEL_SHA256) as info:
            resolve_model(spec, cache_dir=cache, search_shared=False)
        assert f"to {cache / 'yolox_nano.onnx'}" in str(info.value)
    assert served.fetched == [model_store.DEFAULT_MODEL_URL] * 2 and not any(cache.iterdir())


def test_a_redirect_away_from_https_is_refused():
    handler = model_store._HttpsOnlyRedirects()
    request = urllib.request.Request(URL)
    with pytest.raises(urllib.error.URLError, match="not https"):
        handler.redirect_request(request, None, 302, "Found", {}, "http://mirror.example.org/model.onnx")
    assert handler.redirect_request(request, None, 302, "Found", {}, "https://cdn.example.org/m.onnx").full_url == (
        "https://cdn.example.org/m.onnx")


def test_default_model_spec():
    spec = ModelSpec()
    assert spec.is_default_model
    assert spec.expected_sha256 == model_store.DEFAULT_MODEL_SHA256
    assert spec.file_name == "yolox_nano.onnx"
    assert ModelSpec(path="/x/y.onnx").expected_sha256 == ""


def test_the_shared_development_copy_is_found_by_default(model_path, tmp_path):
    if model_path.parent != model_store.shared_model_dir() or os.environ.get(model_store.MODEL_ENV):
        pytest.skip("the model is not at ../shared/models in this checkout")
    assert resolve_model(ModelSpec(), cache_dir=tmp_path, allow_download=False) == model_path
