"""The grid field's marcher (with and without gradients) and the map file round trip and refusals."""

from __future__ import annotations

import hashlib
import io
import struct
from pathlib import Path

import pytest
import torch

from locnerf.field.grid import GridField, GridFieldConfig
from locnerf.field.grid_map import GridMap
from locnerf.field.map_file import FORMAT_VERSION, HEADER, MAGIC, MapFileError, load_map, read_map_info, save_map
from locnerf.field.map_info import MapInfo
from locnerf.field.nerf_pytorch import NERF_PYTORCH_KIND, NerfMLP, NerfPytorchMap
from locnerf.field.protocol import MapNormalization, RadianceMap
from locnerf.maps.source import WORLD, map_identity, open_map
from locnerf.render.camera import PinholeIntrinsics
from locnerf.sim.world import ProceduralWorld, WorldConfig


def _tiny_map(generator: torch.Generator, ndc: bool = False) -> GridMap:
    box = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    field = GridField(box, GridFieldConfig(voxels=12**3, features=4, render_step_factor=1.0), background=(1.0, 1.0, 1.0))
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator) * 3.0)
        field.decoder[2].weight.normal_(generator=generator)
    field.update_occupancy()
    poses = torch.eye(4, dtype=torch.float64).repeat(2, 1, 1)
    poses[:, 2, 3] = torch.tensor([3.0, 3.5])
    intrinsics = PinholeIntrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    return GridMap(field.eval(), MapInfo(MapNormalization(ndc=ndc), intrinsics, poses, {"source": "test"}))


def _rays(generator: torch.Generator, count: int = 64) -> tuple[torch.Tensor, torch.Tensor]:
    origins = torch.tensor([0.0, 0.0, 3.0]) + 0.3 * torch.randn(count, 3, generator=generator)
    directions = torch.cat((0.3 * torch.randn(count, 2, generator=generator), -torch.ones(count, 1)), dim=1)
    return origins, directions


def test_block_marcher_matches_single_pass(generator: torch.Generator) -> None:
    radiance_map = _tiny_map(generator)
    assert isinstance(radiance_map, RadianceMap)
    origins, directions = _rays(generator)
    field = radiance_map.field
    without_termination = GridField(field.box, field.config.model_copy(update={"termination_transmittance": 1e-12}), (1.0, 1.0, 1.0))
    without_termination.load_state_dict(field.state_dict())
    with torch.no_grad():
        single_pass = field.render_training(origins, directions, directions, generator=None).clamp(0, 1)
    blocked = without_termination.render(origins, directions, directions)
    torch.testing.assert_close(blocked, single_pass, atol=1e-5, rtol=0)
    # Early termination changes colours by at most the transmittance it drops.
    terminated = radiance_map.render_rays(origins, directions)
    assert float((terminated - blocked).abs().max()) < 5e-3


def test_occupancy_skipping_keeps_colours(generator: torch.Generator) -> None:
    radiance_map = _tiny_map(generator)
    field = radiance_map.field
    origins, directions = _rays(generator)
    skipped = radiance_map.render_rays(origins, directions)
    field.occupancy.fill_(True)
    field.occupied_box.copy_(field.box)
    full = radiance_map.render_rays(origins, directions)
    # Skipped voxels have one-step opacity below occupancy_alpha = 1e-3 (dilated by one vertex).
    assert float((skipped - full).abs().max()) < 2e-2


def test_config_of_older_map_files_loads() -> None:
    """Older map files store the block marcher's tuning (block_samples, coarse_factor): ignored."""
    config = GridFieldConfig.model_validate({"voxels": 1000, "block_samples": 48, "coarse_factor": 8})
    assert config == GridFieldConfig(voxels=1000)
    with pytest.raises(ValueError, match="unknown_field"):
        GridFieldConfig.model_validate({"unknown_field": 1})


def test_map_file_round_trip(generator: torch.Generator, tmp_path: Path) -> None:
    radiance_map = _tiny_map(generator, ndc=True)
    path = save_map(radiance_map, tmp_path / "tiny.locmap")
    loaded = load_map(path, "cpu")
    origins, directions = _rays(generator)
    torch.testing.assert_close(loaded.render_rays(origins, directions), radiance_map.render_rays(origins, directions))
    assert loaded.normalization == radiance_map.normalization and loaded.default_intrinsics == radiance_map.default_intrinsics
    assert loaded.metadata == {"source": "test"}
    torch.testing.assert_close(loaded.reference_poses(), radiance_map.reference_poses())
    assert [p.name for p in tmp_path.iterdir()] == ["tiny.locmap"]


def test_map_file_refusals(generator: torch.Generator, tmp_path: Path) -> None:
    path = save_map(_tiny_map(generator), tmp_path / "good.locmap")
    data = path.read_bytes()
    assert data.startswith(MAGIC)
    truncated = tmp_path / "truncated.locmap"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFileError, match="truncated"):
        load_map(truncated)
    header_only = tmp_path / "header_only.locmap"
    header_only.write_bytes(data[:30])
    with pytest.raises(MapFileError, match="truncated header"):
        load_map(header_only)
    foreign = tmp_path / "foreign.locmap"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(MapFileError, match="not a locnerf map"):
        load_map(foreign)
    (tmp_path / "text.locmap").write_text("hello")
    with pytest.raises(MapFileError, match="not a locnerf map"):
        load_map(tmp_path / "text.locmap")
    archive = torch.load(io.BytesIO(data[HEADER.size :]), weights_only=True)
    newer_archive = tmp_path / "newer_archive.locmap"
    torch.save({**archive, "version": 99}, newer_archive)
    with pytest.raises(MapFileError, match="version 99 is newer"):
        load_map(newer_archive)
    newer_header = tmp_path / "newer_header.locmap"
    newer_header.write_bytes(data[:8] + struct.pack(">I", 3) + data[12:])
    with pytest.raises(MapFileError, match="version 3 is newer"):
        load_map(newer_header)
    with pytest.raises(FileNotFoundError, match="nothing.locmap"):
        load_map(tmp_path / "nothing.locmap")


def test_tampered_payload_is_refused_by_its_checksum(generator: torch.Generator, tmp_path: Path) -> None:
    data = bytearray(save_map(_tiny_map(generator), tmp_path / "good.locmap").read_bytes())
    for offset in (HEADER.size, HEADER.size + 1000, len(data) - 1):
        tampered = bytearray(data)
        tampered[offset] ^= 0x01
        (tmp_path / "tampered.locmap").write_bytes(bytes(tampered))
        with pytest.raises(MapFileError, match="checksum mismatch"):
            load_map(tmp_path / "tampered.locmap")


def test_version_1_map_files_still_load(generator: torch.Generator, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    radiance_map = _tiny_map(generator)
    data = save_map(radiance_map, tmp_path / "v2.locmap").read_bytes()
    archive = torch.load(io.BytesIO(data[HEADER.size :]), weights_only=True)
    torch.save({**archive, "version": 1}, tmp_path / "v1.locmap")
    loaded = load_map(tmp_path / "v1.locmap")
    origins, directions = _rays(generator)
    torch.testing.assert_close(loaded.render_rays(origins, directions), radiance_map.render_rays(origins, directions))
    assert "no checksum" in caplog.text


class _Payload:
    """What an attacker pickles: unpickling it calls ``Path.touch(marker)``."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def _with_header(payload: bytes) -> bytes:
    """A version-2 file around ``payload`` with a correct checksum, as an attacker would write it."""
    return HEADER.pack(MAGIC, FORMAT_VERSION, len(payload), hashlib.sha256(payload).digest()) + payload


@pytest.mark.parametrize("wrapped", [False, True], ids=["bare_archive", "valid_header"])
def test_map_file_with_code_is_refused_without_running_it(generator: torch.Generator, tmp_path: Path, wrapped: bool) -> None:
    archive = torch.load(io.BytesIO(save_map(_tiny_map(generator), tmp_path / "good.locmap").read_bytes()[HEADER.size :]), weights_only=True)
    marker = tmp_path / "pwned"
    buffer = io.BytesIO()
    torch.save({**archive, "version": FORMAT_VERSION if wrapped else 1, "metadata_hook": _Payload(marker)}, buffer)
    hostile = tmp_path / "hostile.locmap"
    hostile.write_bytes(_with_header(buffer.getvalue()) if wrapped else buffer.getvalue())
    with pytest.raises(MapFileError, match="refused") as refused:
        load_map(hostile)
    assert not marker.exists()
    assert "weights_only" not in str(refused.value) and "weights_only" not in str(refused.value.__cause__ or "")
    # Control: the same bytes do run their code when unpickled without the protection.
    torch.load(io.BytesIO(buffer.getvalue()), weights_only=False)
    assert marker.exists()


def test_interrupted_save_leaves_nothing(generator: torch.Generator, tmp_path: Path) -> None:
    radiance_map = _tiny_map(generator)

    class Interrupted(GridMap):
        def state(self) -> dict:
            raise KeyboardInterrupt

    broken = Interrupted(radiance_map.field, radiance_map.info)
    with pytest.raises(KeyboardInterrupt):
        save_map(broken, tmp_path / "map.locmap")
    assert list(tmp_path.iterdir()) == []


def test_trilinear_lookup_matches_grid_sample(generator: torch.Generator) -> None:
    import torch.nn.functional as F

    box = torch.tensor([[-1.0, -2.0, 0.0], [1.0, 2.0, 3.0]], dtype=torch.float64)
    field = GridField(box, GridFieldConfig(voxels=7 * 13 * 10, features=2), background=None).double()
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator, dtype=torch.float64))
    points = box[0] + (box[1] - box[0]) * (torch.rand(200, 3, generator=generator, dtype=torch.float64) * 1.2 - 0.1)
    rx, ry, rz = field.resolution
    volume = field.grid.detach().t().reshape(1, -1, rz, ry, rx)
    normalised = (2.0 * (points - box[0]) / (box[1] - box[0]) - 1.0).view(1, 1, 1, -1, 3)
    expected = F.grid_sample(volume, normalised, align_corners=True, padding_mode="border").view(volume.shape[1], -1).t()
    torch.testing.assert_close(field.sample_grid(points), expected, atol=1e-12, rtol=0)


def test_trilinear_lookup_gradient_matches_grid_sample(generator: torch.Generator) -> None:
    """Oracle for the scatter backward: the table gradient of a weighted loss equals grid_sample's (float64)."""
    import torch.nn.functional as F

    box = torch.tensor([[-1.0, -2.0, 0.0], [1.0, 2.0, 3.0]], dtype=torch.float64)
    field = GridField(box, GridFieldConfig(voxels=7 * 13 * 10, features=2), background=None).double()
    with torch.no_grad():
        field.grid.copy_(torch.randn(field.grid.shape, generator=generator, dtype=torch.float64))
    # Many points per voxel, so that rows receive several contributions that must add up.
    points = box[0] + (box[1] - box[0]) * torch.rand(3000, 3, generator=generator, dtype=torch.float64)
    upstream = torch.randn(3000, field.grid.shape[1], generator=generator, dtype=torch.float64)
    (field.sample_grid(points) * upstream).sum().backward()
    rx, ry, rz = field.resolution
    volume = field.grid.detach().t().reshape(1, -1, rz, ry, rx).clone().requires_grad_(True)
    normalised = (2.0 * (points - box[0]) / (box[1] - box[0]) - 1.0).view(1, 1, 1, -1, 3)
    sampled = F.grid_sample(volume, normalised, align_corners=True, padding_mode="border").view(volume.shape[1], -1).t()
    (sampled * upstream).sum().backward()
    expected = volume.grad.reshape(volume.shape[1], -1).t()
    torch.testing.assert_close(field.grid.grad, expected, atol=1e-10, rtol=0)


def test_a_map_is_identified_by_the_checksum_of_its_content(generator: torch.Generator, tmp_path: Path) -> None:
    """A saved or loaded map's checksum is the SHA-256 of the file's payload, the same for the same content; the
    world's is fixed by its configuration; a map never saved has none, which a service refuses to serve."""
    radiance_map = _tiny_map(generator)
    with pytest.raises(ValueError, match="GridMap has no checksum"):
        map_identity(radiance_map)
    path = save_map(radiance_map, tmp_path / "a.locnerf")
    assert radiance_map.checksum == hashlib.sha256(path.read_bytes()[HEADER.size :]).hexdigest()
    assert map_identity(load_map(path)) == radiance_map.checksum == map_identity(open_map(str(path), torch.device("cpu")))
    assert save_map(load_map(path), tmp_path / "copy.locnerf").read_bytes() == path.read_bytes()  # same content, same identity
    other = _tiny_map(torch.Generator().manual_seed(99))
    save_map(other, tmp_path / "b.locnerf")
    assert other.checksum != radiance_map.checksum
    world = open_map(WORLD, torch.device("cpu"))
    assert map_identity(world) == ProceduralWorld.default().checksum != ProceduralWorld(WorldConfig(seed=8)).checksum
    assert len(world.checksum) == 64 and int(world.checksum, 16) >= 0


def _archive_of(radiance_map: GridMap, tmp_path: Path) -> dict:
    """The archive dict a saved ``radiance_map`` holds."""
    return torch.load(io.BytesIO(save_map(radiance_map, tmp_path / "good.locmap").read_bytes()[HEADER.size :]), weights_only=True)


def _crafted(archive: dict, path: Path) -> Path:
    """``archive`` written as a version-2 map file with a correct checksum (the damage is in its content, not its bytes)."""
    buffer = io.BytesIO()
    torch.save(archive, buffer)
    path.write_bytes(_with_header(buffer.getvalue()))
    return path


def _with_state(archive: dict, **changes) -> dict:
    return {**archive, "state": {**archive["state"], **changes}}


def _with_weights(archive: dict, **changes) -> dict:
    return _with_state(archive, weights={**archive["state"]["weights"], **changes})


def test_malformed_state_behind_a_valid_checksum_is_refused_with_its_reason(generator: torch.Generator, tmp_path: Path) -> None:
    """A map file whose checksum holds but whose content is not a map's: refused as MapFileError naming the entry
    (before: KeyError, RuntimeError from load_state_dict, or pydantic's error, not a MapFileError)."""
    archive = _archive_of(_tiny_map(generator), tmp_path)
    weights = archive["state"]["weights"]
    info_without_poses = {key: value for key, value in archive["info"].items() if key != "reference_poses"}
    cases = {
        "missing weights": {**archive, "state": {k: v for k, v in archive["state"].items() if k != "weights"}},
        "missing reference_poses": {**archive, "info": info_without_poses},
        r"weights.grid: shape \(2196, 8\), expected \(2197, 8\)": _with_weights(archive, grid=weights["grid"][:-1]),
        r"decoder.0.weight of shape \(64, 5\), expected \(64, 19\)": _with_weights(archive, **{"decoder.0.weight": weights["decoder.0.weight"][:, :5]}),
        r"missing \['occupied_box'\]": _with_state(archive, weights={k: v for k, v in weights.items() if k != "occupied_box"}),
        "entry 'box' is a list, expected Tensor": _with_state(archive, box=[[-1.0] * 3, [1.0] * 3]),
        r"box .*expected low < high": _with_state(archive, box=torch.tensor([[1.0, -1.0, -1.0], [-1.0, 1.0, 1.0]])),
        "reference_poses: shape": {**archive, "info": {**archive["info"], "reference_poses": torch.zeros(2, 3, 4, dtype=torch.float64)}},
        "normalization: scale: Input should be greater than 0": {**archive, "info": {**archive["info"], "normalization": {"scale": -1.0}}},
    }
    for reason, content in cases.items():
        with pytest.raises(MapFileError, match=f"bad.locmap: (grid state|map info).*{reason}"):
            load_map(_crafted(content, tmp_path / "bad.locmap"))
    with pytest.raises(MapFileError, match="bad.locmap: map info: missing reference_poses"):  # what `locnerf map info` reads
        read_map_info(_crafted(cases["missing reference_poses"], tmp_path / "bad.locmap"))


def test_a_grid_larger_than_the_file_holds_is_refused_before_it_is_allocated(generator: torch.Generator, tmp_path: Path) -> None:
    """A crafted resolution or vertex budget cannot make loading allocate: above MAX_GRID_VERTICES (2**27) it is refused
    as such, below it the stored grid must have that many vertices (before: the grid was allocated first, e.g. 10¹⁵
    vertices for a resolution of 10⁵ per axis: a raw RuntimeError, or the machine's memory)."""
    archive = _archive_of(_tiny_map(generator), tmp_path)
    huge = _with_state(archive, resolution=[100_000, 100_000, 100_000])
    with pytest.raises(MapFileError, match=r"resolution \[100000, 100000, 100000\] is 1000000000000000 vertices, more than the 134217728"):
        load_map(_crafted(huge, tmp_path / "huge.locmap"))
    budget = _with_state(archive, config={**archive["state"]["config"], "voxels": 10**12})
    with pytest.raises(MapFileError, match="config: voxels: Input should be less than or equal to 134217728"):
        load_map(_crafted(budget, tmp_path / "budget.locmap"))
    unbacked = _with_state(archive, resolution=[300, 300, 300])  # 27M vertices (860 MB) the file does not hold
    with pytest.raises(MapFileError, match=r"weights.grid: shape \(2197, 8\), expected \(27000000, 8\)"):
        load_map(_crafted(unbacked, tmp_path / "unbacked.locmap"))
    for resolution in ([12, 12], [12, 12, 1], [12.0, 12, 12]):
        with pytest.raises(MapFileError, match="expected three integers >= 2"):
            load_map(_crafted(_with_state(archive, resolution=resolution), tmp_path / "shape.locmap"))


def test_a_nerf_pytorch_map_with_malformed_networks_is_refused(generator: torch.Generator, tmp_path: Path) -> None:
    archive = _archive_of(_tiny_map(generator), tmp_path)
    network = {name: value.detach().clone() for name, value in NerfMLP().state_dict().items()}
    state = {"network_fn_state_dict": network, "network_fine_state_dict": network, "white_background": False}
    nerf = {**archive, "kind": NERF_PYTORCH_KIND, "state": state}
    assert isinstance(load_map(_crafted(nerf, tmp_path / "nerf.locmap")), NerfPytorchMap)
    without_fine = {**nerf, "state": {k: v for k, v in state.items() if k != "network_fine_state_dict"}}
    with pytest.raises(MapFileError, match="nerf.locmap: nerf-pytorch state: missing network_fine_state_dict"):
        load_map(_crafted(without_fine, tmp_path / "nerf.locmap"))
    narrow = {**nerf, "state": {**state, "network_fn_state_dict": {**network, "rgb_linear.weight": torch.zeros(3, 64)}}}
    with pytest.raises(MapFileError, match=r"rgb_linear.weight of shape \(3, 64\), expected \(3, 128\)"):
        load_map(_crafted(narrow, tmp_path / "nerf.locmap"))
