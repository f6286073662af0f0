// Compiled framing of TensorBoard event-file records for routine_gym.plumbing.scalars.
//
// An event file is a sequence of TFRecords: the data's length (uint64, little-endian), the
// masked CRC-32C of those 8 bytes (uint32), the data (a serialized `Event`), and the masked
// CRC-32C of the data (uint32). TensorBoard's Python writer computes CRC-32C one byte at a time
// in Python, ~25 µs for a step's event of a dozen scalars; here it is a table-driven loop in C++
// (Castagnoli polynomial, reflected 0x82F63B78, initial and final XOR 0xFFFFFFFF; masked as
// TensorFlow masks it: rotate right by 15 bits, add 0xA282EAD8).
//
// tests/test_scalars.py checks `masked_crc32c` and `frame` against TensorBoard's own Python
// functions on random data, and that TensorBoard's reader (which checks both CRCs) reads what
// the writer wrote.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cstdint>
#include <cstring>

namespace {

struct Table {
  uint32_t entry[256];
  Table() {
    for (uint32_t i = 0; i < 256; ++i) {
      uint32_t crc = i;
      for (int bit = 0; bit < 8; ++bit) crc = (crc >> 1) ^ (0x82F63B78u & (0u - (crc & 1u)));
      entry[i] = crc;
    }
  }
};

const Table kTable;

uint32_t crc32c(const unsigned char* data, Py_ssize_t size) {
  uint32_t crc = 0xFFFFFFFFu;
  for (Py_ssize_t i = 0; i < size; ++i) crc = kTable.entry[(crc ^ data[i]) & 0xFFu] ^ (crc >> 8);
  return crc ^ 0xFFFFFFFFu;
}

uint32_t masked(uint32_t crc) { return ((crc >> 15) | (crc << 17)) + 0xA282EAD8u; }

void put_le(unsigned char* out, uint64_t value, int bytes) {
  for (int i = 0; i < bytes; ++i) out[i] = static_cast<unsigned char>(value >> (8 * i));
}

PyObject* masked_crc32c(PyObject*, PyObject* args) {
  Py_buffer data;
  if (!PyArg_ParseTuple(args, "y*", &data)) return nullptr;
  const uint32_t crc = masked(crc32c(static_cast<const unsigned char*>(data.buf), data.len));
  PyBuffer_Release(&data);
  return PyLong_FromUnsignedLong(crc);
}

PyObject* frame(PyObject*, PyObject* args) {
  Py_buffer data;
  if (!PyArg_ParseTuple(args, "y*", &data)) return nullptr;
  PyObject* out = PyBytes_FromStringAndSize(nullptr, data.len + 16);
  if (out != nullptr) {
    auto* p = reinterpret_cast<unsigned char*>(PyBytes_AS_STRING(out));
    put_le(p, static_cast<uint64_t>(data.len), 8);
    put_le(p + 8, masked(crc32c(p, 8)), 4);
    std::memcpy(p + 12, data.buf, data.len);
    put_le(p + 12 + data.len,
           masked(crc32c(static_cast<const unsigned char*>(data.buf), data.len)), 4);
  }
  PyBuffer_Release(&data);
  return out;
}

PyMethodDef kMethods[] = {
    {"masked_crc32c", masked_crc32c, METH_VARARGS,
     "masked_crc32c(data) -> int: TensorFlow's masked CRC-32C of a bytes-like object."},
    {"frame", frame, METH_VARARGS,
     "frame(data) -> bytes: `data` as one TFRecord (length, its masked CRC-32C, data, the "
     "data's masked CRC-32C)."},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef kModule = {
    PyModuleDef_HEAD_INIT, "_records",
    "TFRecord framing for TensorBoard event files (see the source's header).",
    -1, kMethods, nullptr, nullptr, nullptr, nullptr,
};

}  // namespace

PyMODINIT_FUNC PyInit__records(void) { return PyModule_Create(&kModule); }
