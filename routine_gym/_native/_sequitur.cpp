// Compiled core of routine_gym.sequitur: the same Sequitur, step for step, in C++17.
//
// `routine_gym/sequitur.py` holds the readable reference (`_induce_python`) and the docs; this
// file ports it one function to one function so both give the same grammar on every input:
//
//   - symbols live in flat arrays `val` / `nxt` / `prv` indexed by symbol id, with the same
//     encoding: action `a` is `2a`, a reference to rule `r` is `2r + 1`, a guard is `-1`;
//   - the digram table maps `(v1 << 32) | v2` to the first symbol of the indexed occurrence,
//     here an open-addressing hash table (linear probing, backward-shift deletion);
//   - the reference recurses check -> match -> substitute -> check. The recursion can be as deep
//     as the grammar, so here it is an explicit stack of continuations on the heap: each
//     frame is the rest of a Python call that was waiting on a nested `check`, and frames run in
//     last-in first-out order, which is exactly the order the recursive calls return in.
//
// Python validates the input and encodes it (episodes joined by separator terminals); `induce`
// here takes that encoded int64 buffer, runs with the GIL released, and returns the live rules
// numbered in order of first appearance as two bytes objects of native int64:
//   offsets (num_rules + 1 entries; rule i is codes[offsets[i]:offsets[i + 1]]) and
//   codes (terminal a -> 2a, separators included; reference to rule number k -> 2k + 1).

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cstdint>
#include <cstring>
#include <new>
#include <utility>
#include <vector>

namespace {

using Id = int32_t;  // symbol id; the input length is capped so that ids fit
constexpr Id kNil = -1;
constexpr int64_t kGuard = -1;
// Ids, rule numbers and the values in a digram key must stay below these bounds.
constexpr Py_ssize_t kMaxInput = Py_ssize_t{1} << 28;

inline uint64_t digram_key(int64_t v1, int64_t v2) {
  return (static_cast<uint64_t>(v1) << 32) | static_cast<uint64_t>(v2);
}

// Digram key -> symbol id. Keys are built from non-negative values below 2**32, so the
// all-ones key never occurs and marks an empty slot.
class DigramTable {
 public:
  DigramTable() { rehash(1 << 12); }

  // The id stored under `key`, or kNil.
  Id find(uint64_t key) const {
    for (size_t i = home(key);; i = (i + 1) & mask_) {
      const Slot& slot = slots_[i];
      if (slot.key == key) return slot.id;
      if (slot.key == kEmpty) return kNil;
    }
  }

  // Stores `id` under `key` when the key is absent and returns kNil; else returns the stored id.
  Id find_or_insert(uint64_t key, Id id) {
    size_t i = home(key);
    for (;; i = (i + 1) & mask_) {
      Slot& slot = slots_[i];
      if (slot.key == key) return slot.id;
      if (slot.key == kEmpty) break;
    }
    slots_[i] = Slot{key, id};
    if (++size_ * 2 > slots_.size()) rehash(slots_.size() * 2);
    return kNil;
  }

  void assign(uint64_t key, Id id) {
    size_t i = home(key);
    for (;; i = (i + 1) & mask_) {
      Slot& slot = slots_[i];
      if (slot.key == key) {
        slot.id = id;
        return;
      }
      if (slot.key == kEmpty) break;
    }
    slots_[i] = Slot{key, id};
    if (++size_ * 2 > slots_.size()) rehash(slots_.size() * 2);
  }

  // Removes `key` only while it still points at `id` (another occurrence may own it).
  void erase_if(uint64_t key, Id id) {
    size_t i = home(key);
    for (;; i = (i + 1) & mask_) {
      const Slot& slot = slots_[i];
      if (slot.key == key) break;
      if (slot.key == kEmpty) return;
    }
    if (slots_[i].id != id) return;
    // Backward-shift deletion: pull later entries of the probe run into the hole, so lookups
    // never need tombstones.
    for (size_t j = i;;) {
      j = (j + 1) & mask_;
      if (slots_[j].key == kEmpty) break;
      const size_t h = home(slots_[j].key);
      if (((j - h) & mask_) >= ((j - i) & mask_)) {
        slots_[i] = slots_[j];
        i = j;
      }
    }
    slots_[i].key = kEmpty;
    --size_;
  }

 private:
  struct Slot {
    uint64_t key;
    Id id;
  };
  static constexpr uint64_t kEmpty = ~uint64_t{0};

  size_t home(uint64_t key) const {
    return static_cast<size_t>((key * 0x9E3779B97F4A7C15ULL) >> shift_);
  }

  void rehash(size_t capacity) {
    std::vector<Slot> old;
    old.swap(slots_);
    slots_.assign(capacity, Slot{kEmpty, kNil});
    mask_ = capacity - 1;
    shift_ = 64;
    for (size_t c = capacity; c > 1; c >>= 1) --shift_;
    for (const Slot& slot : old) {
      if (slot.key == kEmpty) continue;
      size_t i = home(slot.key);
      while (slots_[i].key != kEmpty) i = (i + 1) & mask_;
      slots_[i] = slot;
    }
  }

  std::vector<Slot> slots_;
  size_t mask_ = 0;
  int shift_ = 64;
  size_t size_ = 0;
};

class Sequitur {
 public:
  explicit Sequitur(size_t n) {
    // A symbol per input value, plus a reference and a guard and two body symbols per rule.
    const size_t guess = n + n / 2 + 16;
    val_.reserve(guess);
    nxt_.reserve(guess);
    prv_.reserve(guess);
    guard_rule_.reserve(guess);
    start_ = new_rule();
  }

  void append(int64_t v) {
    const Id g = guard_[start_];
    const Id s = new_symbol(v);
    insert_after(prv_[g], s);
    check(prv_[s]);
    run();
  }

  // Live rules from the start rule, numbered in order of first appearance (as `_collect`).
  void collect(std::vector<int64_t>& offsets, std::vector<int64_t>& codes) const {
    std::vector<int64_t> number(guard_.size(), -1);
    std::vector<Id> order{start_};
    number[start_] = 0;
    offsets.push_back(0);
    for (size_t i = 0; i < order.size(); ++i) {
      const Id g = guard_[order[i]];
      for (Id s = nxt_[g]; s != g; s = nxt_[s]) {
        const int64_t v = val_[s];
        if (v & 1) {
          const int64_t child = v >> 1;
          if (number[child] < 0) {
            number[child] = static_cast<int64_t>(order.size());
            order.push_back(static_cast<Id>(child));
          }
          codes.push_back(2 * number[child] + 1);
        } else {
          codes.push_back(v);
        }
      }
      offsets.push_back(static_cast<int64_t>(codes.size()));
    }
  }

 private:
  // What is left of a reference call once the `check` it is waiting on has returned.
  enum class Step : int32_t {
    kCheckPair,      // substitute's tail: `if not check(q): check(nxt[q])`   (a = q)
    kSubstituteS,    // match, new rule: `substitute(s, r)` after `substitute(m, r)` (a = s, b = r)
    kFinishNewRule,  // match, new rule: index the body digram, then rule utility (b = r)
    kFinishReuse,    // match, reused rule: rule utility (b = r)
  };
  struct Frame {
    Step step;
    Id a;
    Id b;
  };

  Id new_symbol(int64_t v) {
    val_.push_back(v);
    nxt_.push_back(kNil);
    prv_.push_back(kNil);
    guard_rule_.push_back(kNil);
    if (v >= 0 && (v & 1)) ++count_[v >> 1];
    return static_cast<Id>(val_.size() - 1);
  }

  Id new_rule() {
    const Id r = static_cast<Id>(guard_.size());
    const Id g = new_symbol(kGuard);
    nxt_[g] = g;
    prv_[g] = g;
    guard_.push_back(g);
    count_.push_back(0);
    guard_rule_[g] = r;
    return r;
  }

  void delete_digram(Id s) {
    const Id n = nxt_[s];
    const int64_t vs = val_[s], vn = val_[n];
    if (vs < 0 || vn < 0) return;
    table_.erase_if(digram_key(vs, vn), s);
  }

  void join(Id left, Id right) {
    if (nxt_[left] != kNil) {
      delete_digram(left);
      // In a run like `aaa` only the first `aa` is indexed; when a symbol of the run is
      // removed, the overlapping digram that remains must be indexed instead.
      const Id rp = prv_[right], rn = nxt_[right];
      int64_t v = val_[right];
      if (rp != kNil && rn != kNil && v >= 0 && v == val_[rp] && v == val_[rn]) {
        table_.assign(digram_key(v, v), right);
      }
      const Id lp = prv_[left], ln = nxt_[left];
      v = val_[left];
      if (lp != kNil && ln != kNil && v >= 0 && v == val_[lp] && v == val_[ln]) {
        table_.assign(digram_key(v, v), lp);
      }
    }
    nxt_[left] = right;
    prv_[right] = left;
  }

  void insert_after(Id x, Id y) {
    join(y, nxt_[x]);
    join(x, y);
  }

  void remove(Id x) {  // `delete` in the reference
    join(prv_[x], nxt_[x]);
    delete_digram(x);
    const int64_t v = val_[x];
    if (v >= 0 && (v & 1)) --count_[v >> 1];
  }

  // Indexes the digram at `s`, or resolves it if it already occurs; true when it occurred.
  bool check(Id s) {
    const Id n = nxt_[s];
    const int64_t vs = val_[s], vn = val_[n];
    if (vs < 0 || vn < 0) return false;
    const Id m = table_.find_or_insert(digram_key(vs, vn), s);
    if (m == kNil) return false;
    if (nxt_[m] != s && m != s) match(s, m);  // overlapping occurrences (`aaa`) are left alone
    return true;
  }

  // The edits of `substitute(s, r)`; its trailing checks are pushed as a frame.
  void substitute(Id s, Id r) {
    const Id q = prv_[s];
    remove(nxt_[q]);
    remove(nxt_[q]);
    insert_after(q, new_symbol(2 * static_cast<int64_t>(r) + 1));
    stack_.push_back(Frame{Step::kCheckPair, q, 0});
  }

  void match(Id s, Id m) {
    const Id pm = prv_[m], nn = nxt_[nxt_[m]];
    if (val_[pm] == kGuard && val_[nn] == kGuard) {
      // The earlier occurrence is the whole body of a rule: reuse that rule.
      const Id r = guard_rule_[pm];
      stack_.push_back(Frame{Step::kFinishReuse, 0, r});
      substitute(s, r);
    } else {
      const Id r = new_rule();
      const Id g = guard_[r];
      insert_after(prv_[g], new_symbol(val_[s]));
      insert_after(prv_[g], new_symbol(val_[nxt_[s]]));
      stack_.push_back(Frame{Step::kFinishNewRule, 0, r});
      stack_.push_back(Frame{Step::kSubstituteS, s, r});
      substitute(m, r);
    }
  }

  // Rule utility: the rule at the head of r's body may now be used only once.
  void enforce_utility(Id r) {
    const Id first = nxt_[guard_[r]];
    const int64_t v = val_[first];
    if (v >= 0 && (v & 1) && count_[v >> 1] == 1) expand(first);
  }

  // `s` is the last use of its rule: put the rule's body in its place.
  void expand(Id s) {
    const Id left = prv_[s], right = nxt_[s];
    const Id r = static_cast<Id>(val_[s] >> 1);
    const Id g = guard_[r];
    const Id f = nxt_[g], last = prv_[g];
    delete_digram(s);
    join(left, f);
    join(last, right);
    const int64_t vl = val_[last], vr = val_[right];
    if (vl >= 0 && vr >= 0) table_.assign(digram_key(vl, vr), last);
    count_[r] = 0;
    guard_rule_[g] = kNil;
  }

  void run() {
    while (!stack_.empty()) {
      const Frame frame = stack_.back();
      stack_.pop_back();
      switch (frame.step) {
        case Step::kCheckPair:
          if (!check(frame.a)) check(nxt_[frame.a]);
          break;
        case Step::kSubstituteS:
          substitute(frame.a, frame.b);
          break;
        case Step::kFinishNewRule: {
          const Id first = nxt_[guard_[frame.b]];
          const int64_t v1 = val_[first], v2 = val_[nxt_[first]];
          // The reference stores this key unchecked; a key with a guard in it could never be
          // looked up, so leaving it out changes nothing.
          if (v1 >= 0 && v2 >= 0) table_.assign(digram_key(v1, v2), first);
          enforce_utility(frame.b);
          break;
        }
        case Step::kFinishReuse:
          enforce_utility(frame.b);
          break;
      }
    }
  }

  std::vector<int64_t> val_;
  std::vector<Id> nxt_;
  std::vector<Id> prv_;
  std::vector<Id> guard_rule_;  // rule of each live guard symbol, else kNil
  std::vector<Id> guard_;       // guard symbol of each rule
  std::vector<int64_t> count_;  // references to each rule
  DigramTable table_;
  std::vector<Frame> stack_;
  Id start_ = 0;
};

PyObject* bytes_of(const std::vector<int64_t>& v) {
  return PyBytes_FromStringAndSize(reinterpret_cast<const char*>(v.data()),
                                   static_cast<Py_ssize_t>(v.size() * sizeof(int64_t)));
}

PyObject* induce(PyObject* /*module*/, PyObject* arg) {
  Py_buffer view;
  if (PyObject_GetBuffer(arg, &view, PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) != 0) return nullptr;
  const char* fmt = view.format != nullptr ? view.format : "B";
  const bool is_int64 = view.itemsize == 8 && (std::strcmp(fmt, "q") == 0 ||
                                               std::strcmp(fmt, "l") == 0 ||
                                               std::strcmp(fmt, "<q") == 0 ||
                                               std::strcmp(fmt, "=q") == 0);
  const bool is_bytes = std::strcmp(fmt, "B") == 0 && view.itemsize == 1 && view.len % 8 == 0;
  if (!is_int64 && !is_bytes) {
    PyErr_Format(PyExc_TypeError, "expected a buffer of native int64, got format '%s'", fmt);
    PyBuffer_Release(&view);
    return nullptr;
  }
  const Py_ssize_t n = view.len / 8;
  if (n >= kMaxInput) {
    PyErr_Format(PyExc_ValueError, "at most %zd encoded symbols, got %zd", kMaxInput - 1, n);
    PyBuffer_Release(&view);
    return nullptr;
  }
  const char* data = static_cast<const char*>(view.buf);

  std::vector<int64_t> offsets, codes;
  bool out_of_memory = false;
  Py_BEGIN_ALLOW_THREADS
  try {
    Sequitur sequitur(static_cast<size_t>(n));
    for (Py_ssize_t i = 0; i < n; ++i) {
      int64_t v;
      std::memcpy(&v, data + 8 * i, 8);  // bytes objects need not be 8-byte aligned
      sequitur.append(v);
    }
    sequitur.collect(offsets, codes);
  } catch (const std::bad_alloc&) {
    out_of_memory = true;
  }
  Py_END_ALLOW_THREADS
  PyBuffer_Release(&view);
  if (out_of_memory) return PyErr_NoMemory();

  PyObject* off = bytes_of(offsets);
  if (off == nullptr) return nullptr;
  PyObject* cod = bytes_of(codes);
  if (cod == nullptr) {
    Py_DECREF(off);
    return nullptr;
  }
  return Py_BuildValue("(NN)", off, cod);
}

// Reads a bytes-like argument of native int64 into a vector (copied: bytes need not be aligned).
bool read_int64s(PyObject* arg, std::vector<int64_t>& out) {
  Py_buffer view;
  if (PyObject_GetBuffer(arg, &view, PyBUF_C_CONTIGUOUS) != 0) return false;
  if (view.len % 8 != 0) {
    PyErr_Format(PyExc_ValueError, "expected a buffer of native int64, got %zd bytes", view.len);
    PyBuffer_Release(&view);
    return false;
  }
  out.resize(static_cast<size_t>(view.len / 8));
  if (view.len > 0) std::memcpy(out.data(), view.buf, static_cast<size_t>(view.len));
  PyBuffer_Release(&view);
  return true;
}

// `Grammar.expansion_lengths` and `Grammar.expansions(max_length)` of the reference, on the
// flat rules `induce` returns: each rule's length, and the expansions of rules 1.. of at most
// `max_length` actions (all when it is negative), end to end in rule order. A rule of at most
// `max_length` actions has only rules at most as long below it, so each is expanded by a walk
// of its own tree, without memo.
PyObject* expansions(PyObject* /*module*/, PyObject* args) {
  PyObject* offsets_arg;
  PyObject* codes_arg;
  long long max_action, max_length;
  if (!PyArg_ParseTuple(args, "OOLL", &offsets_arg, &codes_arg, &max_action, &max_length)) {
    return nullptr;
  }
  std::vector<int64_t> offsets, codes;
  if (!read_int64s(offsets_arg, offsets) || !read_int64s(codes_arg, codes)) return nullptr;
  const size_t num_rules = offsets.empty() ? 0 : offsets.size() - 1;
  for (size_t i = 0; i < num_rules; ++i) {
    if (offsets[i] < 0 || offsets[i] > offsets[i + 1] ||
        offsets[i + 1] > static_cast<int64_t>(codes.size())) {
      PyErr_SetString(PyExc_ValueError, "rule offsets out of order or out of range");
      return nullptr;
    }
  }
  for (const int64_t c : codes) {
    if (c < 0 || ((c & 1) && static_cast<size_t>(c >> 1) >= num_rules)) {
      PyErr_SetString(PyExc_ValueError, "a code is negative or refers to no rule");
      return nullptr;
    }
  }

  std::vector<int64_t> lengths(num_rules, -1), out;
  bool cyclic = false, out_of_memory = false;
  Py_BEGIN_ALLOW_THREADS
  try {
    // Lengths by an iterative post-order walk (grammars can be 2^20 rules deep); a rule is
    // marked -2 while its children are pending, which also catches a cycle.
    std::vector<size_t> stack;
    for (size_t root = 0; root < num_rules && !cyclic; ++root) {
      if (lengths[root] >= 0) continue;
      stack.push_back(root);
      while (!stack.empty() && !cyclic) {
        const size_t r = stack.back();
        if (lengths[r] >= 0) {
          stack.pop_back();
          continue;
        }
        bool pending = false;
        int64_t total = 0;
        for (int64_t i = offsets[r]; i < offsets[r + 1]; ++i) {
          const int64_t c = codes[i];
          if (!(c & 1)) {
            total += (c >> 1) <= max_action ? 1 : 0;  // an episode separator counts 0
          } else if (lengths[c >> 1] >= 0) {
            total += lengths[c >> 1];
          } else if (lengths[c >> 1] == -2) {
            cyclic = true;
            break;
          } else {
            stack.push_back(static_cast<size_t>(c >> 1));
            pending = true;
          }
        }
        if (cyclic) break;
        if (pending) {
          lengths[r] = -2;  // visited; children first
          continue;
        }
        lengths[r] = total;
        stack.pop_back();
      }
      // A rule marked -2 and popped back with all children known is finished above; the
      // marks only stay on a cycle.
    }
    if (!cyclic) {
      std::vector<std::pair<int64_t, int64_t>> walk;  // (rule, next code index)
      for (size_t r = 1; r < num_rules; ++r) {
        if (max_length >= 0 && lengths[r] > max_length) continue;
        walk.emplace_back(static_cast<int64_t>(r), offsets[r]);
        while (!walk.empty()) {
          auto& [rule, i] = walk.back();
          if (i == offsets[rule + 1]) {
            walk.pop_back();
            continue;
          }
          const int64_t c = codes[i++];
          if (c & 1) {
            walk.emplace_back(c >> 1, offsets[(c >> 1)]);
          } else {
            out.push_back(c >> 1);
          }
        }
      }
    }
  } catch (const std::bad_alloc&) {
    out_of_memory = true;
  }
  Py_END_ALLOW_THREADS
  if (out_of_memory) return PyErr_NoMemory();
  if (cyclic) {
    PyErr_SetString(PyExc_ValueError, "the rules refer to each other in a cycle");
    return nullptr;
  }
  PyObject* len = bytes_of(lengths);
  if (len == nullptr) return nullptr;
  PyObject* exp = bytes_of(out);
  if (exp == nullptr) {
    Py_DECREF(len);
    return nullptr;
  }
  return Py_BuildValue("(NN)", len, exp);
}

PyMethodDef methods[] = {
    {"induce", induce, METH_O,
     "induce(encoded) -> (offsets, codes)\n\n"
     "Sequitur on an encoded symbol buffer (native int64; terminal a as 2a). Returns two bytes\n"
     "objects of native int64: rule body offsets and the bodies, rules numbered in order of\n"
     "first appearance and references to rule k encoded as 2k + 1."},
    {"expansions", expansions, METH_VARARGS,
     "expansions(offsets, codes, max_action, max_length) -> (lengths, flat)\n\n"
     "On `induce`'s output: each rule's length in actions (episode separators, terminals\n"
     "above max_action, count 0), and the actions of every rule 1.. of at most max_length\n"
     "actions (every rule when max_length < 0), end to end in rule order; native int64 bytes."},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef module_def = {
    PyModuleDef_HEAD_INIT, "routine_gym._native._sequitur",
    "Compiled core of routine_gym.sequitur (use routine_gym.sequitur.induce).", -1, methods,
    nullptr, nullptr, nullptr, nullptr,
};

}  // namespace

PyMODINIT_FUNC PyInit__sequitur(void) { return PyModule_Create(&module_def); }
