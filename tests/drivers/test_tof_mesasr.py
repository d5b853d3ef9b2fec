"""The libMesaSR backend: library loading, declared signatures, and a whole grab through ctypes
against a small stand-in libmesasr.so compiled from C here (same exported API as MESA's)."""

from __future__ import annotations

import ctypes
import shutil
import subprocess
from ctypes import POINTER, c_float, c_int, c_ubyte, c_uint, c_ushort, c_void_p
from types import SimpleNamespace

import numpy as np
import pytest

import drivers.tof as tof
from drivers.base import DeviceError
from drivers.tof import constants as k
from drivers.tof import mesasr

FAKE_LIBMESASR = r"""
#include <string.h>
#include <stdio.h>
typedef struct { int imgType; int dataType; void* data; unsigned short width, height; } ImgEntry;
enum { W = 176, H = 144 };
static int opened, fail, mode = 0x400, freq = 1, acquisitions;
static unsigned char integration = 30;
static unsigned short threshold, dist[W * H], amp[W * H], conf[W * H];
static unsigned char ae[4] = {0xff, 0, 0, 0};
static ImgEntry list[3];
static int cam_object;

int SR_OpenUSB(void** cam, unsigned int serial) {
  if (serial != 0 && serial != 0x4000002Fu) return -1;
  *cam = &cam_object; opened = 1; return 1;
}
int SR_Close(void* cam) { opened = 0; return 0; }
unsigned int SR_GetRows(void* cam) { return H; }
unsigned int SR_GetCols(void* cam) { return W; }
void SR_SetTimeout(void* cam, int ms) {}
int SR_GetVersion(unsigned short v[4]) { v[0] = 1; v[1] = 2; v[2] = 3; v[3] = 4; return 0; }
int SR_Acquire(void* cam) {
  if (fail || !opened) return -1;
  for (int i = 0; i < W * H; i++) {
    dist[i] = 0x4000; amp[i] = (unsigned short)(1000 + i % W);
    conf[i] = i < W ? 0 : 0xffff;      /* first row: no confidence */
  }
  if (ae[0] != 0xff && integration < ae[1]) integration++;
  acquisitions++;
  return W * H * 6;
}
int SR_GetImageList(void* cam, ImgEntry** out) {
  ImgEntry e0 = {0, 3, dist, W, H}, e1 = {1, 3, amp, W, H}, e2 = {8, 3, conf, W, H};
  list[0] = e0; list[1] = e1; list[2] = e2;
  *out = list; return (mode & 0x100) ? 3 : 2;
}
int SR_CoordTrfFlt(void* cam, float* x, float* y, float* z, int px, int py, int pz) {
  for (int i = 0; i < W * H; i++) {   /* libMesaSR frame: x left, y up */
    *(float*)((char*)x + i * px) = 0.5f;
    *(float*)((char*)y + i * py) = 0.25f;
    *(float*)((char*)z + i * pz) = 1.25f;
  }
  return 0;
}
int SR_SetIntegrationTime(void* cam, unsigned char t) { integration = t; return 0; }
unsigned char SR_GetIntegrationTime(void* cam) { return integration; }
int SR_SetModulationFrequency(void* cam, int f) {
  if (f != 1 && f != 6 && f != 8 && f != 9 && f != 10 && f != 11) return -1;
  freq = f; return 0;
}
int SR_GetModulationFrequency(void* cam) { return freq; }
int SR_SetAmplitudeThreshold(void* cam, unsigned short v) { threshold = v; return 0; }
unsigned short SR_GetAmplitudeThreshold(void* cam) { return threshold; }
int SR_SetMode(void* cam, int m) { mode = m; return 0; }
int SR_GetMode(void* cam) { return mode; }
int SR_SetAutoExposure(void* cam, unsigned char a, unsigned char b, unsigned char c, unsigned char d) {
  ae[0] = a; ae[1] = b; ae[2] = c; ae[3] = d; return 0;
}
int SR_GetDeviceString(void* cam, char* buf, int len) {
  return snprintf(buf, len, "VendorID:0x%04x, ProductID:0x%04x, Manufacturer:'%s', Product:'%s'",
                  0x1ad2, 0x0075, "MESA Imaging AG", "SR4000");
}
unsigned int SR_ReadSerial(void* cam) { return 0x4000002Fu; }
void FAKE_SetFail(int f) { fail = f; }
int FAKE_Acquisitions(void) { return acquisitions; }
"""


@pytest.fixture(scope="module")
def fake_lib(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler to build the stand-in libmesasr")
    d = tmp_path_factory.mktemp("mesasr")
    (d / "fake.c").write_text(FAKE_LIBMESASR)
    lib = d / "libmesasr.so"
    subprocess.run([cc, "-shared", "-fPIC", "-O1", "-o", str(lib), str(d / "fake.c")], check=True)
    return lib


def test_missing_library_fails_at_open_with_the_fix(monkeypatch):
    monkeypatch.setattr(mesasr.ctypes.util, "find_library", lambda name: None)
    cam = tof.create({"backend": "mesasr", "library": "/nonexistent/libmesasr.so"})  # no error yet
    assert cam.backend == "mesasr" and cam.status()["open"] is False
    with pytest.raises(DeviceError) as err:
        cam.open()
    msg = str(err.value)
    assert err.value.device == "tof" and msg.startswith("tof: libmesasr not found")
    assert "/nonexistent/libmesasr.so" in msg and "libmesasr-dev" in msg and "drivers.tof.library" in msg
    assert "libmesasr not found" in cam.status()["last_error"]


def test_missing_library_without_a_configured_path(monkeypatch):
    monkeypatch.setattr(mesasr.ctypes.util, "find_library", lambda name: None)
    with pytest.raises(DeviceError, match="find_library\\('mesasr'\\) found nothing"):
        tof.create({"backend": "mesasr", "library": None}).open()


def test_every_function_gets_its_libmesasr_signature():
    fake = SimpleNamespace(**{name: SimpleNamespace() for name in mesasr.SIGNATURES})
    mesasr.declare(fake)
    assert fake.SR_OpenUSB.argtypes == [POINTER(c_void_p), c_uint] and fake.SR_OpenUSB.restype is c_int
    assert fake.SR_CoordTrfFlt.argtypes == [c_void_p, POINTER(c_float), POINTER(c_float), POINTER(c_float), c_int, c_int, c_int]
    assert fake.SR_GetImageList.argtypes == [c_void_p, POINTER(POINTER(mesasr.ImgEntry))]
    assert fake.SR_SetIntegrationTime.argtypes == [c_void_p, c_ubyte]
    assert fake.SR_SetAmplitudeThreshold.argtypes == [c_void_p, c_ushort]
    assert fake.SR_SetAutoExposure.argtypes == [c_void_p, c_ubyte, c_ubyte, c_ubyte, c_ubyte]
    assert fake.SR_ReadSerial.restype is c_uint and fake.SR_SetTimeout.restype is None
    for name in ("SR_Close", "SR_Acquire", "SR_GetRows", "SR_GetCols", "SR_SetMode", "SR_GetDeviceString"):
        assert getattr(fake, name).argtypes[0] is c_void_p
    # ImgEntry matches definesSR.h: two enums, a pointer, two unsigned shorts.
    assert [f[0] for f in mesasr.ImgEntry._fields_] == ["imgType", "dataType", "data", "width", "height"]

    partial = SimpleNamespace(SR_OpenUSB=SimpleNamespace())
    with pytest.raises(DeviceError, match="lacks .*SR_Acquire"):
        mesasr.declare(partial)


def test_a_grab_through_ctypes(fake_lib):
    cam = tof.create({"backend": "mesasr", "library": str(fake_lib), "undistort": False})
    cam.open()
    info = cam.query()
    assert info["serial"] == "0x4000002F" and info["product_id"] == "0x0075" and info["product"] == "SR4000"
    assert cam.check()["integration"] == 30

    d = cam.grab("distance", integrate=3)
    expected = 0x4000 / 0xFFFF * k.unambiguous_range(30.0)
    assert np.isnan(d[0]).all()  # confidence 0: never used
    assert np.allclose(d[1:], expected, atol=1e-5)
    amp = cam.grab("amplitude")
    assert amp[5, 7] == 1007.0

    xyz, amplitude = cam.grab_xyz(2)
    assert (xyz[0] == -1).all()
    # libMesaSR's x-left/y-up frame comes out as OpenCV's x-right/y-down.
    assert np.allclose(xyz[1:], [-0.5, -0.25, 1.25])
    assert amplitude[0, 3] == 1003.0

    cam.set_modulation(15)
    assert cam.check()["modulation_mhz"] == 15.0
    assert cam._cam._lib.SR_GetModulationFrequency(cam._cam._handle) == k.ModulationFrq.MF_15MHz
    cam.set_correction_modes(median=True)
    assert cam.get_mode() & k.AcquireMode.AM_MEDIAN and cam.get_mode() & k.AcquireMode.AM_SW_TRIGGER
    assert cam._cam.library_version() == "4.3.2.1"

    # Auto exposure: the stand-in raises the integration by one per frame up to its maximum.
    cam.set_auto_exposure(True, 1, 40, 5, 70, max_iterations=30)
    cam.set_integration(30)
    cam.grab("distance")
    st = cam.status()
    assert st["exposure_settled"] is True and cam.check()["integration"] == 40

    cam._cam._lib.FAKE_SetFail(1)
    with pytest.raises(DeviceError, match="SR_Acquire failed") as err:
        cam.grab("z")
    assert err.value.device == "tof"
    cam._cam._lib.FAKE_SetFail(0)
    cam.reset()
    assert cam.grab("z").shape == (k.HEIGHT, k.WIDTH)
    cam.close()
    assert cam.status()["open"] is False


def test_no_camera_with_that_serial(fake_lib):
    cam = tof.create({"backend": "mesasr", "library": str(fake_lib), "serial": "0x40000001"})
    with pytest.raises(DeviceError, match="no SR4000 with serial 0x40000001"):
        cam.open()


def test_imgentry_layout_matches_c():
    # int, int, pointer, ushort, ushort with natural alignment.
    assert ctypes.sizeof(mesasr.ImgEntry) == (24 if ctypes.sizeof(c_void_p) == 8 else 16)
