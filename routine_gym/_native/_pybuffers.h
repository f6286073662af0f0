// Py_buffer handling shared by the compiled modules (_minatar_core.cpp, _masked_gru.cpp).
#ifndef ROUTINE_GYM_PYBUFFERS_H_
#define ROUTINE_GYM_PYBUFFERS_H_

#include <Python.h>

namespace routine_gym {
namespace {  // internal linkage: each module has its own copy

// Holds the Py_buffers of one call and releases them on every way out.
struct Buffers {
  static constexpr int kMax = 24;
  Py_buffer views[kMax];
  int count = 0;
  ~Buffers() {
    for (int i = 0; i < count; ++i) PyBuffer_Release(&views[i]);
  }
  // A C-contiguous buffer of `obj` holding exactly `bytes` bytes; nullptr (with a Python error
  // set) otherwise. `optional`: None gives nullptr with no error.
  void* get(PyObject* obj, Py_ssize_t bytes, bool writable, const char* name,
            bool optional = false) {
    if (optional && obj == Py_None) return nullptr;
    Py_buffer* view = &views[count];
    int flags = PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) != 0) return nullptr;
    ++count;
    if (view->len != bytes) {
      PyErr_Format(PyExc_ValueError, "%s holds %zd bytes, expected %zd", name, view->len, bytes);
      return nullptr;
    }
    return view->buf;
  }
  // A C-contiguous buffer of `obj` holding a whole number of `T`s: how many, or -1 with a
  // Python error set.
  template <typename T>
  Py_ssize_t count_of(PyObject* obj, const char* name) {
    Py_buffer* view = &views[count];
    if (PyObject_GetBuffer(obj, view, PyBUF_C_CONTIGUOUS) != 0) return -1;
    ++count;
    if (view->len % static_cast<Py_ssize_t>(sizeof(T)) != 0) {
      PyErr_Format(PyExc_ValueError, "%s holds %zd bytes, not whole %zd-byte items", name,
                   view->len, static_cast<Py_ssize_t>(sizeof(T)));
      return -1;
    }
    return view->len / static_cast<Py_ssize_t>(sizeof(T));
  }
};

}  // namespace
}  // namespace routine_gym

#endif  // ROUTINE_GYM_PYBUFFERS_H_
