"""The recordings read frame by frame (mantis_rig.video.recording): .cine (8-, 16-bit, packed
10-bit) written by the simulated camera's writer, raw and FFV1 .avi, folders of frames and one
picture; the rate rules; damaged files refused naming the frame, with the frames before kept."""
from pathlib import Path
import struct

import cv2
import numpy as np
import pytest

from mantis_rig.video.recording import Frame, RecordingError, open_recording, rate_from_name
from mantis_sim.camera.cine_writer import CineWriter, frame_time_s
from mantis_sim.errors import InputError

W, H = 30, 20          # 30: a DIB pads its rows to 32 bytes


def pictures(n, seed=0, dtype=np.uint8, top=255):
    rng = np.random.default_rng(seed)
    return [rng.integers(0, top + 1, (H, W)).astype(dtype) for _ in range(n)]


def write_cine(path, frames, rate_hz=19000.0, first_number=-4, bit_depth=8):
    with CineWriter(path, W, H, len(frames), rate_hz, first_number, bit_depth) as w:
        for f in frames:
            w.write(f)
    return path


def read_all(recording):
    """(frames read, the error that ended the reading or None)."""
    got = []
    try:
        for frame in recording.frames():
            got.append(frame)
    except RecordingError as exc:
        return got, exc
    return got, None


def write_avi(path, frames, fourcc=0):
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, fourcc, 30.0, (W, H), False)
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def write_dib_avi(path, frames, palette=None):
    """An 8-bit DIB .avi as the camera's software writes it: a grey palette, rows bottom-up,
    each padded to 4 bytes, in '00db' chunks, with an idx1 index."""
    stride = (W + 3) & ~3
    palette = np.column_stack([np.arange(256)] * 3 + [np.zeros(256, int)]) if palette is None \
        else palette
    strf = struct.pack('<IiiHHIIiiII', 40, W, H, 1, 8, 0, stride * H, 0, 0, 256, 0)
    strf += palette.astype(np.uint8).tobytes()

    def chunk(fourcc, body):
        return fourcc + struct.pack('<I', len(body)) + body + b'\0' * (len(body) & 1)

    def lst(kind, body):
        return chunk(b'LIST', kind + body)
    avih = struct.pack('<14I', 33333, 0, 0, 0x10, len(frames), 0, 1, 0, W, H, 0, 0, 0, 0)
    strh = b'vids' + b'\0' * 4 + struct.pack('<IHHIIIIIIIIhhhh', 0, 0, 0, 0, 1, 30, 0,
                                             len(frames), 0, 0, 0, 0, 0, W, H)
    hdrl = lst(b'hdrl', chunk(b'avih', avih) + lst(b'strl', chunk(b'strh', strh)
                                                     + chunk(b'strf', strf)))
    bodies = []
    for f in frames:
        padded = np.zeros((H, stride), np.uint8)
        padded[:, :W] = f[::-1]
        bodies.append(chunk(b'00db', padded.tobytes()))
    movi = lst(b'movi', b''.join(bodies))
    riff = b'AVI ' + hdrl + movi
    path.write_bytes(b'RIFF' + struct.pack('<I', len(riff)) + riff)
    return path


# ------------------------------------------------------------------------------------ .cine
def test_an_8_bit_cine_reads_back_frames_numbers_times_rate_and_trigger(tmp_path):
    frames = pictures(12)
    path = write_cine(tmp_path / 'strike.cine', frames)
    with open_recording(path) as rec:
        assert (rec.width, rec.height, rec.frame_count, rec.bit_depth) == (W, H, 12, 8)
        assert rec.rate_hz == 19000.0 and rec.rate_source == 'the .cine header'
        assert rec.trigger_index == 4
        got = list(rec.frames())
        part = list(rec.frames(3, 6))
    assert [f.index for f in got] == list(range(-4, 8))
    assert [f.time_s for f in got] == [frame_time_s(n, 19000.0) for n in range(-4, 8)]
    assert got[4].time_s == 0.0 and got[5].time_s == pytest.approx(1 / 19000, abs=1e-9)
    for frame, original in zip(got, frames, strict=True):
        assert frame.image.dtype == np.uint8
        np.testing.assert_array_equal(frame.image, original)
    assert [f.index for f in part] == [-1, 0, 1]
    assert isinstance(got[0], Frame)


def test_a_16_bit_cine_keeps_its_pixels_and_depth(tmp_path):
    frames = pictures(5, dtype=np.uint16, top=4095)
    path = write_cine(tmp_path / 'deep.cine', frames, rate_hz=2000.0, first_number=0,
                      bit_depth=12)
    with open_recording(path) as rec:
        assert rec.bit_depth == 12 and rec.trigger_index == 0
        got = list(rec.frames())
    for frame, original in zip(got, frames, strict=True):
        assert frame.image.dtype == np.uint16
        np.testing.assert_array_equal(frame.image, original)


def test_a_packed_10_bit_cine_is_unpacked_and_linearised(tmp_path):
    from pycine.linLUT import linLUT
    W10 = 32                # four pixels in five bytes: a multiple of 4 wide
    rng = np.random.default_rng(3)
    values = [rng.integers(0, 1024, (H, W10)) for _ in range(3)]
    packed = []
    for v in values:          # four 10-bit pixels in five bytes, the first pixel's high bits first
        q = v.reshape(H, W10 // 4, 4)
        b = np.stack([q[..., 0] >> 2, ((q[..., 0] & 3) << 6) | (q[..., 1] >> 4),
                      ((q[..., 1] & 15) << 4) | (q[..., 2] >> 6),
                      ((q[..., 2] & 63) << 2) | (q[..., 3] >> 8), q[..., 3] & 255], axis=-1)
        packed.append(b.reshape(H, W10 * 5 // 4).astype(np.uint8))
    path = tmp_path / 'p10.cine'
    with CineWriter(path, W10 * 5 // 4, H, 3, 19000.0) as w:
        for p in packed:
            w.write(p)
    data = bytearray(path.read_bytes())
    struct.pack_into('<iiHHI', data, 44 + 4, W10, H, 1, 16, 256)   # biWidth .. biCompression
    path.write_bytes(bytes(data))
    with open_recording(path) as rec:
        assert (rec.width, rec.bit_depth) == (W10, 12)
        got = list(rec.frames())
    for frame, v in zip(got, values, strict=True):
        np.testing.assert_array_equal(frame.image, np.asarray(linLUT)[v])


def test_a_truncated_cine_keeps_the_frames_before_and_names_the_frame(tmp_path):
    path = write_cine(tmp_path / 'cut.cine', pictures(10))
    data = path.read_bytes()
    frame_bytes = 8 + W * H
    path.write_bytes(data[:len(data) - 3 * frame_bytes - frame_bytes // 2])  # inside frame 6
    with open_recording(path) as rec:
        got, error = read_all(rec)
    assert len(got) == 6
    assert error is not None and isinstance(error, InputError)
    assert 'cut.cine' in str(error) and 'frame 6' in str(error)


def test_a_cine_picture_of_another_size_is_refused_naming_the_frame(tmp_path):
    path = write_cine(tmp_path / 'odd.cine', pictures(6))
    data = bytearray(path.read_bytes())
    with open_recording(path) as rec:
        offset = int(rec._offsets[2])
    struct.pack_into('<I', data, offset + 4, W * H - 10)
    path.write_bytes(bytes(data))
    with open_recording(path) as rec:
        got, error = read_all(rec)
    assert len(got) == 2 and 'frame 2' in str(error) and 'odd.cine' in str(error)


@pytest.mark.parametrize('content', [b'', b'CI' + b'\0' * 30, b'not a cine at all' * 50])
def test_a_file_that_is_no_cine_is_refused(tmp_path, content):
    path = tmp_path / 'bad.cine'
    path.write_bytes(content)
    with pytest.raises(RecordingError, match='bad.cine'):
        open_recording(path)


def test_a_cine_rate_given_must_agree_with_its_header(tmp_path):
    path = write_cine(tmp_path / 's.cine', pictures(2))
    assert open_recording(path, rate_hz=19000.0).rate_hz == 19000.0
    with pytest.raises(RecordingError, match='contradicts'):
        open_recording(path, rate_hz=8000.0)


# ------------------------------------------------------------------------------------- .avi
def test_a_raw_avi_reads_back_its_frames_with_the_rate_given(tmp_path):
    frames = pictures(8, seed=1)
    path = write_avi(tmp_path / 'raw.avi', frames)
    with open_recording(path, rate_hz=8000.0) as rec:
        assert type(rec).__name__ == 'RawAvi'
        assert (rec.width, rec.height, rec.frame_count) == (W, H, 8)
        assert (rec.rate_hz, rec.rate_source, rec.trigger_index) == (8000.0, '--rate', None)
        got = list(rec.frames())
    assert [f.index for f in got] == list(range(8))
    assert [f.time_s for f in got] == [k / 8000.0 for k in range(8)]
    for frame, original in zip(got, frames, strict=True):
        np.testing.assert_array_equal(frame.image, original)


def test_a_dib_avi_as_the_camera_software_writes_it(tmp_path):
    frames = pictures(4, seed=2)
    with open_recording(write_dib_avi(tmp_path / 'dib.avi', frames), rate_hz=2000) as rec:
        assert type(rec).__name__ == 'RawAvi'
        got = list(rec.frames())
    for frame, original in zip(got, frames, strict=True):
        np.testing.assert_array_equal(frame.image, original)
    inverted = np.column_stack([255 - np.arange(256)] * 3 + [np.zeros(256, int)])
    with open_recording(write_dib_avi(tmp_path / 'inv.avi', frames, inverted),
                        rate_hz=2000) as rec:
        np.testing.assert_array_equal(next(rec.frames()).image, 255 - frames[0])


def test_an_ffv1_avi_is_lossless(tmp_path):
    frames = pictures(6, seed=4)
    path = write_avi(tmp_path / 'ffv1.avi', frames, cv2.VideoWriter_fourcc(*'FFV1'))
    with open_recording(path, rate_hz=10000.0) as rec:
        assert type(rec).__name__ == 'DecodedAvi' and rec.frame_count == 6
        got = list(rec.frames())
        later = list(rec.frames(4))
    for frame, original in zip(got, frames, strict=True):
        np.testing.assert_array_equal(frame.image, original)
    np.testing.assert_array_equal(later[0].image, frames[4])


def test_the_avi_rate_comes_from_the_cine_beside_it_or_the_trials_name(tmp_path):
    frames = pictures(2)
    avi = write_avi(tmp_path / '111319_11kfps_T_2X_A_2.avi', frames)
    with open_recording(avi) as rec:
        assert (rec.rate_hz, rec.rate_source) == (11000.0, "the trial's name (11kfps)")
    write_cine(tmp_path / '111319_11kfps_T_2X_A_2.cine', frames, rate_hz=10000.0)
    with open_recording(avi) as rec:
        assert (rec.rate_hz, rec.rate_source) == (10000.0, 'the .cine beside it')
    with open_recording(avi, rate_hz=6000) as rec:
        assert (rec.rate_hz, rec.rate_source) == (6000.0, '--rate')
    assert rate_from_name('air_2p5kfps_1') == 2500.0 and rate_from_name('trial_3') is None


def test_an_avi_whose_rate_is_nowhere_is_refused_asking_for_it(tmp_path):
    avi = write_avi(tmp_path / 'video.avi', pictures(2))
    with pytest.raises(RecordingError, match='--rate'):
        open_recording(avi)
    with pytest.raises(RecordingError, match='positive'):
        open_recording(avi, rate_hz=-5.0)


def test_a_truncated_raw_avi_keeps_the_frames_before_and_names_the_frame(tmp_path):
    path = write_dib_avi(tmp_path / 'cut.avi', pictures(6))
    data = path.read_bytes()
    stride = (W + 3) & ~3
    movi_start = data.index(b'00db')
    path.write_bytes(data[:movi_start + 3 * (8 + stride * H) + 30])      # inside frame 3
    with open_recording(path, rate_hz=1000) as rec:
        got, error = read_all(rec)
    assert len(got) == 3 and 'frame 3' in str(error) and 'cut.avi' in str(error)


def test_a_raw_avi_frame_of_another_size_is_refused_naming_it(tmp_path):
    path = write_dib_avi(tmp_path / 'odd.avi', pictures(4))
    data = bytearray(path.read_bytes())
    second = data.index(b'00db', data.index(b'00db') + 1)
    struct.pack_into('<I', data, second + 4, W * H)       # 30 x 20 bytes, not 32 x 20
    path.write_bytes(bytes(data))
    with open_recording(path, rate_hz=1000) as rec:
        got, error = read_all(rec)
    assert len(got) == 1 and 'frame 1' in str(error)


def test_a_damaged_ffv1_avi_keeps_the_frames_before(tmp_path):
    frames = pictures(10, seed=5)
    path = write_avi(tmp_path / 'cut.avi', frames, cv2.VideoWriter_fourcc(*'FFV1'))
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * 0.8)])
    with open_recording(path, rate_hz=1000) as rec:
        got, error = read_all(rec)
    assert 0 < len(got) < 10 and f'frame {len(got)}' in str(error)
    for frame, original in zip(got, frames):
        np.testing.assert_array_equal(frame.image, original)


def test_a_file_that_is_no_avi_is_refused(tmp_path):
    path = tmp_path / 'x.avi'
    path.write_bytes(b'RIFF\x10\x00\x00\x00WAVEfmt ')
    with pytest.raises(RecordingError, match='x.avi'):
        open_recording(path, rate_hz=1000)


# --------------------------------------------------------------------- frames and pictures
def test_a_folder_of_frames_in_natural_order_colour_made_grey(tmp_path):
    frames = pictures(11, seed=6)
    folder = tmp_path / 'air_8kfps_frames'
    folder.mkdir()
    for k, f in enumerate(frames):
        rgba = cv2.cvtColor(f, cv2.COLOR_GRAY2BGRA) if k % 2 else f
        cv2.imwrite(str(folder / f'frame{k}.png'), rgba)
    (folder / 'notes.txt').write_text('not a frame')
    with open_recording(folder) as rec:
        assert (rec.frame_count, rec.rate_hz) == (11, 8000.0)
        got = list(rec.frames())
    for frame, original in zip(got, frames, strict=True):
        np.testing.assert_array_equal(frame.image, original)


def test_16_bit_tiff_frames_stay_16_bit(tmp_path):
    frames = pictures(2, dtype=np.uint16, top=65535)
    for k, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f'f{k}.tif'), f)
    with open_recording(tmp_path, rate_hz=100) as rec:
        assert rec.bit_depth == 16
        np.testing.assert_array_equal(list(rec.frames())[1].image, frames[1])


def test_a_folder_frame_of_another_size_or_unreadable_is_refused_naming_it(tmp_path):
    for k, f in enumerate(pictures(3)):
        cv2.imwrite(str(tmp_path / f'f{k}.png'), f)
    cv2.imwrite(str(tmp_path / 'f3.png'), np.zeros((H + 1, W), np.uint8))
    (tmp_path / 'f4.png').write_bytes(b'\x89PNG damaged')
    with open_recording(tmp_path, rate_hz=100) as rec:
        got, error = read_all(rec)
    assert len(got) == 3 and 'f3.png' in str(error) and 'frame 3' in str(error)
    with open_recording(tmp_path, rate_hz=100) as rec:
        with pytest.raises(RecordingError, match='f4.png: frame 4'):
            list(rec.frames(4))
    empty = tmp_path / 'empty'
    empty.mkdir()
    with pytest.raises(RecordingError, match='no TIFF or PNG'):
        open_recording(empty, rate_hz=100)


def test_one_picture_is_a_recording_of_one_frame(tmp_path):
    f = pictures(1)[0]
    path = tmp_path / '031320_19kfps_T_1.png'
    cv2.imwrite(str(path), cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
    with open_recording(path) as rec:
        assert (rec.frame_count, rec.rate_hz) == (1, 19000.0)
        (frame,) = rec.frames()
    np.testing.assert_array_equal(frame.image, f)
    plain = tmp_path / 'picture.png'
    cv2.imwrite(str(plain), f)
    with open_recording(plain) as rec:
        assert rec.rate_hz is None and np.isnan(next(rec.frames()).time_s)


def test_what_is_no_recording_is_refused(tmp_path):
    with pytest.raises(RecordingError, match='no such file'):
        open_recording(tmp_path / 'missing.cine')
    other = tmp_path / 'x.mp3'
    other.write_bytes(b'x')
    with pytest.raises(RecordingError, match='not a recording'):
        open_recording(other)
    assert Path(other).exists()
