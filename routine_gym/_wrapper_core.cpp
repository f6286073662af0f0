// Compiled step of routine_gym.wrapper.RoutineActionWrapper.
//
// `Stepper(env, sequences, num_primitive_actions, length, action_space, obs_shape, obs_dtype)`
// holds what the wrapper's `step` reads; `Stepper.step(action)` runs the primitive action or the
// routine on `env` and returns the same five values as the Python step in wrapper.py (which
// stays the reference and the fallback): the last observation, the summed reward (a float
// added up in the same order), the last inner `terminated`/`truncated` objects, and the last
// inner info extended with the `routine_*` keys of routine_gym.macro_info.
//
// What makes it cheaper than the Python step, beyond the loop being C:
// - The per-step info arrays are recycled. A small ring holds the arrays of the last steps; a
//   step reuses a slot's arrays only when the ring's reference is the only one left (nobody
//   else can see them, the way CPython's `zip` reuses its result tuple) and they still have
//   the shape, dtype and flags they were made with; otherwise it makes new ones and the
//   consumer keeps the old. A consumer that keeps an array therefore never sees it change,
//   and a consumer that copies and drops the info (SyncVectorEnv, any loop that rebinds
//   `info`) costs no allocation.
// - Each observation is copied into its row of the stacked array as it arrives (a memcpy when
//   it is a C-contiguous array of the space's dtype and shape, numpy's item assignment
//   otherwise), so an env that returns the same array object every step is recorded right.
// - Reused arrays get their padding back only where the last use wrote.
//
// tests/test_wrapper_core.py checks it against the Python step on random actions, routines,
// episode ends, observation spaces and kept or dropped infos.

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#define NPY_NO_DEPRECATED_API NPY_1_7_API_VERSION
#include <numpy/arrayobject.h>

#include <cstdint>
#include <cstring>
#include <vector>

namespace {

constexpr int kRing = 4;  // steps whose arrays the ring holds
constexpr int kArrays = 5;  // actions, rewards, terminated, truncated, observations
enum { kActions, kRewards, kTerminated, kTruncated, kObservations };

PyObject* kKeys[kArrays + 2];  // routine_index, routine_length, then one per array
const char* const kKeyNames[kArrays + 2] = {
    "routine_index",      "routine_length",    "routine_actions",     "routine_rewards",
    "routine_terminated", "routine_truncated", "routine_observations",
};
PyObject* kStepName;

struct Slot {
  PyArrayObject* arrays[kArrays];
  Py_ssize_t written;  // leading rows written by the last step that used the slot
};

struct Stepper {
  PyObject_HEAD
  PyObject* env;
  PyObject* sequences;  // tuple of tuples of int: each action's primitive actions
  PyObject* action_space;  // for error messages
  Py_ssize_t num_actions;  // n + K
  Py_ssize_t num_primitive;  // n
  Py_ssize_t length;  // L, every array's first dimension
  std::vector<int64_t>* table;  // [num_actions, length] padded primitive actions
  bool record;  // observations on
  PyArray_Descr* obs_descr;  // the observation space's dtype (record only)
  std::vector<npy_intp>* obs_dims;  // [length, *obs_shape] (record only)
  Py_ssize_t obs_row_bytes;
  Slot ring[kRing];
  unsigned next_slot;
};

void clear_slot(Slot* slot) {
  for (auto& array : slot->arrays) Py_CLEAR(array);
  slot->written = 0;
}

int traverse(PyObject* self_obj, visitproc visit, void* arg) {
  auto* self = reinterpret_cast<Stepper*>(self_obj);
  Py_VISIT(Py_TYPE(self_obj));
  Py_VISIT(self->env);
  Py_VISIT(self->sequences);
  Py_VISIT(self->action_space);
  return 0;
}

int clear(PyObject* self_obj) {
  auto* self = reinterpret_cast<Stepper*>(self_obj);
  Py_CLEAR(self->env);
  Py_CLEAR(self->sequences);
  Py_CLEAR(self->action_space);
  return 0;
}

void dealloc(PyObject* self_obj) {
  auto* self = reinterpret_cast<Stepper*>(self_obj);
  PyTypeObject* type = Py_TYPE(self_obj);
  PyObject_GC_UnTrack(self_obj);
  clear(self_obj);
  for (auto& slot : self->ring) clear_slot(&slot);
  Py_CLEAR(self->obs_descr);
  delete self->table;
  delete self->obs_dims;
  type->tp_free(self_obj);
  Py_DECREF(type);
}

int init(PyObject* self_obj, PyObject* args, PyObject* kwargs) {
  auto* self = reinterpret_cast<Stepper*>(self_obj);
  static const char* kwlist[] = {"env",          "sequences", "num_primitive_actions",
                                 "length",       "action_space", "obs_shape",
                                 "obs_dtype",    nullptr};
  PyObject *env, *sequences, *action_space, *obs_shape, *obs_dtype;
  Py_ssize_t num_primitive, length;
  if (!PyArg_ParseTupleAndKeywords(args, kwargs, "OO!nnOOO", const_cast<char**>(kwlist), &env,
                                   &PyTuple_Type, &sequences, &num_primitive, &length,
                                   &action_space, &obs_shape, &obs_dtype)) {
    return -1;
  }
  if (self->table != nullptr) {
    PyErr_SetString(PyExc_RuntimeError, "Stepper is already initialised");
    return -1;
  }
  const Py_ssize_t num_actions = PyTuple_GET_SIZE(sequences);
  if (length < 1 || num_primitive < 0 || num_primitive > num_actions) {
    PyErr_SetString(PyExc_ValueError, "Stepper needs length >= 1 and 0 <= n <= len(sequences)");
    return -1;
  }
  auto table = new std::vector<int64_t>(static_cast<size_t>(num_actions * length), -1);
  for (Py_ssize_t a = 0; a < num_actions; ++a) {
    PyObject* sequence = PyTuple_GET_ITEM(sequences, a);
    if (!PyTuple_Check(sequence) || PyTuple_GET_SIZE(sequence) < 1 ||
        PyTuple_GET_SIZE(sequence) > length) {
      delete table;
      PyErr_Format(PyExc_ValueError, "sequence %zd must be a tuple of 1 to %zd actions", a,
                   length);
      return -1;
    }
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(sequence); ++i) {
      const long long value = PyLong_AsLongLong(PyTuple_GET_ITEM(sequence, i));
      if (value == -1 && PyErr_Occurred()) {
        delete table;
        return -1;
      }
      (*table)[a * length + i] = value;
    }
  }
  self->record = obs_shape != Py_None;
  if (self->record) {
    PyArray_Descr* descr = nullptr;
    if (!PyArray_DescrConverter(obs_dtype, &descr)) {
      delete table;
      return -1;
    }
    auto dims = new std::vector<npy_intp>{length};
    PyObject* shape = PySequence_Tuple(obs_shape);
    if (shape == nullptr) {
      delete table;
      delete dims;
      Py_DECREF(descr);
      return -1;
    }
    Py_ssize_t row = descr->elsize;
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(shape); ++i) {
      const Py_ssize_t dim = PyLong_AsSsize_t(PyTuple_GET_ITEM(shape, i));
      if (dim < 0) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "negative observation shape");
        Py_DECREF(shape);
        delete table;
        delete dims;
        Py_DECREF(descr);
        return -1;
      }
      dims->push_back(dim);
      row *= dim;
    }
    Py_DECREF(shape);
    self->obs_descr = descr;
    self->obs_dims = dims;
    self->obs_row_bytes = row;
  }
  Py_INCREF(env);
  self->env = env;
  Py_INCREF(sequences);
  self->sequences = sequences;
  Py_INCREF(action_space);
  self->action_space = action_space;
  self->num_actions = num_actions;
  self->num_primitive = num_primitive;
  self->length = length;
  self->table = table;
  return 0;
}

// The type and shape an array of the slot is made with; a reused array must still have them.
int array_type(int which) {
  switch (which) {
    case kActions: return NPY_INT64;
    case kRewards: return NPY_FLOAT64;
    default: return NPY_BOOL;
  }
}

// Strong references to a slot's arrays, released on every way out of `step`.
struct Hold {
  PyArrayObject* arrays[kArrays];
  explicit Hold(const Slot* slot) {
    for (int k = 0; k < kArrays; ++k) {
      arrays[k] = slot->arrays[k];
      Py_XINCREF(arrays[k]);
    }
  }
  ~Hold() {
    for (auto& array : arrays) Py_XDECREF(array);
  }
};

bool intact(const Stepper* self, const Slot* slot) {
  const int count = self->record ? kArrays : kObservations;
  for (int k = 0; k < count; ++k) {
    PyArrayObject* array = slot->arrays[k];
    if (array == nullptr || Py_REFCNT(array) != 1 || !PyArray_CheckExact(array) ||
        !PyArray_ISCARRAY(array)) {
      return false;
    }
    if (k == kObservations) {
      const auto& dims = *self->obs_dims;
      if (PyArray_NDIM(array) != static_cast<int>(dims.size()) ||
          !PyArray_EquivTypes(PyArray_DESCR(array), self->obs_descr)) {
        return false;
      }
      for (size_t d = 0; d < dims.size(); ++d) {
        if (PyArray_DIM(array, static_cast<int>(d)) != dims[d]) return false;
      }
    } else if (PyArray_NDIM(array) != 1 || PyArray_DIM(array, 0) != self->length ||
               PyArray_TYPE(array) != array_type(k)) {
      return false;
    }
  }
  return true;
}

// Fresh arrays for the slot, holding their padding: actions -1, the rest zeros.
bool fill_slot(Stepper* self, Slot* slot) {
  clear_slot(slot);
  npy_intp dims[1] = {self->length};
  const int count = self->record ? kArrays : kObservations;
  for (int k = 0; k < count; ++k) {
    PyObject* array;
    if (k == kObservations) {
      Py_INCREF(self->obs_descr);
      array = PyArray_Zeros(static_cast<int>(self->obs_dims->size()), self->obs_dims->data(),
                            self->obs_descr, 0);
    } else {
      array = PyArray_ZEROS(1, dims, array_type(k), 0);
    }
    if (array == nullptr) {
      clear_slot(slot);
      return false;
    }
    slot->arrays[k] = reinterpret_cast<PyArrayObject*>(array);
  }
  // Our own references for the length of the step: a re-entrant step (an inner env that
  // steps this wrapper, or another thread while the inner env has released the GIL) sees them
  // as held and cannot replace or reuse them under this one.
  Hold hold(slot);
  auto* actions = static_cast<int64_t*>(PyArray_DATA(slot->arrays[kActions]));
  for (Py_ssize_t i = 0; i < self->length; ++i) actions[i] = -1;
  return true;
}

// Copy one observation into row `row` of the stacked array.
bool store_observation(Stepper* self, PyArrayObject* stacked, Py_ssize_t row, PyObject* obs) {
  if (PyArray_CheckExact(obs)) {
    auto* array = reinterpret_cast<PyArrayObject*>(obs);
    const auto& dims = *self->obs_dims;
    bool same = PyArray_IS_C_CONTIGUOUS(array) &&
                PyArray_NDIM(array) == static_cast<int>(dims.size()) - 1 &&
                PyArray_EquivTypes(PyArray_DESCR(array), self->obs_descr);
    for (size_t d = 1; same && d < dims.size(); ++d) {
      same = PyArray_DIM(array, static_cast<int>(d - 1)) == dims[d];
    }
    if (same) {
      std::memcpy(PyArray_BYTES(stacked) + row * self->obs_row_bytes, PyArray_DATA(array),
                  static_cast<size_t>(self->obs_row_bytes));
      return true;
    }
  }
  PyObject* index = PyLong_FromSsize_t(row);
  if (index == nullptr) return false;
  const int status = PyObject_SetItem(reinterpret_cast<PyObject*>(stacked), index, obs);
  Py_DECREF(index);
  return status == 0;
}

PyObject* bad_action(Stepper* self, PyObject* action, bool integer) {
  if (integer) {
    PyErr_Format(PyExc_ValueError, "action %R is outside the action space %R", action,
                 self->action_space);
  } else {
    PyErr_Format(PyExc_ValueError, "action %R is not an integer action of %R", action,
                 self->action_space);
  }
  return nullptr;
}

PyObject* step(PyObject* self_obj, PyObject* action) {
  auto* self = reinterpret_cast<Stepper*>(self_obj);
  if (self->table == nullptr) {
    PyErr_SetString(PyExc_RuntimeError, "Stepper is not initialised");
    return nullptr;
  }
  // operator.index(action), as the Python step: ints, numpy integers, anything with __index__.
  PyObject* as_int = PyLong_CheckExact(action) ? Py_NewRef(action) : PyNumber_Index(action);
  if (as_int == nullptr) {
    if (!PyErr_ExceptionMatches(PyExc_TypeError)) return nullptr;
    PyErr_Clear();
    return bad_action(self, action, false);
  }
  int overflow = 0;
  const long long value = PyLong_AsLongLongAndOverflow(as_int, &overflow);
  Py_DECREF(as_int);
  if (overflow != 0 || value < 0 || value >= self->num_actions) {
    return bad_action(self, action, true);
  }
  const Py_ssize_t a = static_cast<Py_ssize_t>(value);

  Slot* slot = &self->ring[self->next_slot];
  self->next_slot = (self->next_slot + 1) % kRing;
  Py_ssize_t stale = slot->written;  // rows the last use of these arrays wrote
  if (!intact(self, slot)) {
    if (!fill_slot(self, slot)) return nullptr;
    stale = 0;
  }
  // Our own references for the length of the step: a re-entrant step (an inner env that
  // steps this wrapper, or another thread while the inner env has released the GIL) sees them
  // as held and cannot replace or reuse them under this one.
  Hold hold(slot);
  auto* actions = static_cast<int64_t*>(PyArray_DATA(slot->arrays[kActions]));
  auto* rewards = static_cast<double*>(PyArray_DATA(slot->arrays[kRewards]));
  auto* terminated_row = static_cast<npy_bool*>(PyArray_DATA(slot->arrays[kTerminated]));
  auto* truncated_row = static_cast<npy_bool*>(PyArray_DATA(slot->arrays[kTruncated]));
  PyArrayObject* stacked = self->record ? slot->arrays[kObservations] : nullptr;
  // Flags first: only the last executed entry can be set, and it may move.
  if (stale > 0) {
    std::memset(terminated_row, 0, static_cast<size_t>(stale));
    std::memset(truncated_row, 0, static_cast<size_t>(stale));
  }
  slot->written = self->length;  // until the step ends, all of it may need the padding back

  PyObject* sequence = PyTuple_GET_ITEM(self->sequences, a);
  const Py_ssize_t planned = a < self->num_primitive ? 1 : PyTuple_GET_SIZE(sequence);
  PyObject* result = nullptr;  // the last inner step's 5-tuple
  PyObject* terminated = nullptr;
  PyObject* truncated = nullptr;
  double total = 0.0;
  Py_ssize_t executed = 0;
  bool ended = false;
  while (executed < planned && !ended) {
    // A primitive goes to the inner env as the caller gave it; a routine's actions are ints.
    PyObject* call_args[2] = {self->env,
                              a < self->num_primitive ? action
                                                      : PyTuple_GET_ITEM(sequence, executed)};
    Py_XDECREF(result);
    result = PyObject_VectorcallMethod(kStepName, call_args,
                                       2 | PY_VECTORCALL_ARGUMENTS_OFFSET, nullptr);
    if (result == nullptr) return nullptr;
    if (!PyTuple_CheckExact(result) || PyTuple_GET_SIZE(result) != 5) {
      PyObject* unpacked = PySequence_Tuple(result);
      Py_DECREF(result);
      if (unpacked == nullptr) return nullptr;
      if (PyTuple_GET_SIZE(unpacked) != 5) {
        PyErr_Format(PyExc_ValueError, "env.step returned %zd values, expected 5",
                     PyTuple_GET_SIZE(unpacked));
        Py_DECREF(unpacked);
        return nullptr;
      }
      result = unpacked;
    }
    const double reward = PyFloat_AsDouble(PyTuple_GET_ITEM(result, 1));
    if (reward == -1.0 && PyErr_Occurred()) {
      Py_DECREF(result);
      return nullptr;
    }
    total += reward;
    rewards[executed] = reward;
    if (stacked != nullptr &&
        !store_observation(self, stacked, executed, PyTuple_GET_ITEM(result, 0))) {
      Py_DECREF(result);
      return nullptr;
    }
    terminated = PyTuple_GET_ITEM(result, 2);
    truncated = PyTuple_GET_ITEM(result, 3);
    const int term = PyObject_IsTrue(terminated);
    const int trunc = term < 0 ? -1 : PyObject_IsTrue(truncated);
    if (trunc < 0) {
      Py_DECREF(result);
      return nullptr;
    }
    ++executed;
    if (term || trunc) ended = true;
    if (ended || executed == planned) {
      terminated_row[executed - 1] = static_cast<npy_bool>(term);
      truncated_row[executed - 1] = static_cast<npy_bool>(trunc);
    }
  }
  std::memcpy(actions, &(*self->table)[a * self->length], sizeof(int64_t) * executed);
  // Padding back where the last use wrote and this one did not.
  for (Py_ssize_t i = executed; i < stale; ++i) {
    actions[i] = -1;
    rewards[i] = 0.0;
  }
  if (stacked != nullptr && stale > executed) {
    std::memset(PyArray_BYTES(stacked) + executed * self->obs_row_bytes, 0,
                static_cast<size_t>((stale - executed) * self->obs_row_bytes));
  }
  slot->written = executed;

  PyObject* info = PyTuple_GET_ITEM(result, 4);
  PyObject* index = PyLong_FromSsize_t(a >= self->num_primitive ? a - self->num_primitive : -1);
  PyObject* length = PyLong_FromSsize_t(executed);
  PyObject* total_obj = PyFloat_FromDouble(total);
  bool ok = index != nullptr && length != nullptr && total_obj != nullptr;
  PyObject* values[kArrays + 2] = {index, length};
  for (int k = 0; k < kArrays; ++k) values[k + 2] = reinterpret_cast<PyObject*>(slot->arrays[k]);
  const int count = self->record ? kArrays + 2 : kArrays + 1;
  const bool is_dict = PyDict_CheckExact(info);
  for (int k = 0; ok && k < count; ++k) {
    ok = (is_dict ? PyDict_SetItem(info, kKeys[k], values[k])
                  : PyObject_SetItem(info, kKeys[k], values[k])) == 0;
  }
  PyObject* out = ok ? PyTuple_Pack(5, PyTuple_GET_ITEM(result, 0), total_obj, terminated,
                                    truncated, info)
                     : nullptr;
  Py_XDECREF(index);
  Py_XDECREF(length);
  Py_XDECREF(total_obj);
  Py_DECREF(result);
  return out;
}

PyMethodDef kStepperMethods[] = {
    {"step", step, METH_O,
     "step($self, action, /)\n--\n\nRun the primitive action or routine `action`: "
     "RoutineActionWrapper.step, returning (obs, reward, terminated, truncated, info)."},
    {nullptr, nullptr, 0, nullptr},
};

PyType_Slot kStepperSlots[] = {
    {Py_tp_doc, const_cast<char*>("Stepper(env, sequences, num_primitive_actions, length, "
                                  "action_space, obs_shape, obs_dtype): the compiled step of "
                                  "RoutineActionWrapper (see the source's header).")},
    {Py_tp_init, reinterpret_cast<void*>(init)},
    {Py_tp_new, reinterpret_cast<void*>(PyType_GenericNew)},
    {Py_tp_dealloc, reinterpret_cast<void*>(dealloc)},
    {Py_tp_traverse, reinterpret_cast<void*>(traverse)},
    {Py_tp_clear, reinterpret_cast<void*>(clear)},
    {Py_tp_methods, kStepperMethods},
    {0, nullptr},
};

PyType_Spec kStepperSpec = {
    "routine_gym._wrapper_core.Stepper", sizeof(Stepper), 0,
    Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC, kStepperSlots,
};

PyModuleDef kModule = {
    PyModuleDef_HEAD_INIT, "_wrapper_core",
    "The compiled step of RoutineActionWrapper (see the source's header).",
    -1, nullptr, nullptr, nullptr, nullptr, nullptr,
};

}  // namespace

PyMODINIT_FUNC PyInit__wrapper_core(void) {
  import_array();
  for (int k = 0; k < kArrays + 2; ++k) {
    if (kKeys[k] == nullptr && (kKeys[k] = PyUnicode_InternFromString(kKeyNames[k])) == nullptr) {
      return nullptr;
    }
  }
  if (kStepName == nullptr && (kStepName = PyUnicode_InternFromString("step")) == nullptr) {
    return nullptr;
  }
  PyObject* module = PyModule_Create(&kModule);
  if (module == nullptr) return nullptr;
  PyObject* type = PyType_FromSpec(&kStepperSpec);
  if (type == nullptr || PyModule_AddObject(module, "Stepper", type) != 0) {
    Py_XDECREF(type);
    Py_DECREF(module);
    return nullptr;
  }
  return module;
}
