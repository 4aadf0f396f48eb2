"""Finding, downloading and verifying the model: missing files, checksum mismatches, file:// downloads."""

import hashlib
import os

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


def test_file_url_download_into_the_cache_verified(tmp_path):
    source = tmp_path / "remote" / "model.onnx"
    source.parent.mkdir()
    source.write_bytes(CONTENT)
    cache = tmp_path / "cache"
    spec = ModelSpec(url=source.as_uri(), sha256=CONTENT_SHA)
    path = resolve_model(spec, cache_dir=cache, search_shared=False)
    assert path == cache / "model.onnx" and path.read_bytes() == CONTENT
    source.unlink()  # second time: from the cache, no download
    assert resolve_model(spec, cache_dir=cache, search_shared=False) == path


def test_a_download_with_the_wrong_checksum_leaves_nothing_in_the_cache(tmp_path):
    source = tmp_path / "model.onnx"
    source.write_bytes(CONTENT)
    cache = tmp_path / "cache"
    spec = ModelSpec(url=source.as_uri(), sha256="0" * 64)
    with pytest.raises(ModelError, match="0{64}"):
        resolve_model(spec, cache_dir=cache, search_shared=False)
    assert not any(cache.iterdir())


def test_a_corrupt_cached_file_is_downloaded_again(tmp_path):
    source = tmp_path / "model.onnx"
    source.write_bytes(CONTENT)
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "model.onnx").write_bytes(b"half a file")
    path = resolve_model(ModelSpec(url=source.as_uri(), sha256=CONTENT_SHA), cache_dir=cache, search_shared=False)
    assert path.read_bytes() == CONTENT


def test_unreachable_url_and_disabled_download_say_how_to_get_the_model(tmp_path):
    spec = ModelSpec(url=(tmp_path / "absent.onnx").as_uri(), sha256=CONTENT_SHA)
    with pytest.raises(ModelError, match="cannot download") as info:
        resolve_model(spec, cache_dir=tmp_path / "cache", search_shared=False)
    assert CONTENT_SHA in str(info.value)
    with pytest.raises(ModelError, match="downloads are disabled"):
        resolve_model(spec, cache_dir=tmp_path / "cache", allow_download=False, search_shared=False)
    assert not list((tmp_path / "cache").glob("*.part"))


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
