// Compiled core of routine_gym.envs.minatar_vector for MinAtar's five games (Breakout, Space
// Invaders, Freeway, Asterix, Seaquest): all games of a vector env stepped in one call, each
// through the primitive action or routine it was given (one C++ function, templated on the game).
//
// MinAtar's games (minatar/environments/*.py, Young & Tian 2019) are a few integer or 10×10
// array updates per step; in Python each step of one game costs ~2 µs (Breakout) to ~17 µs
// (Space Invaders, its numpy rolls and sums) for the sticky-action draw, the game's `act`, its
// boolean `state()` frame and the copy into the batch, which on a 16-game vector env is up to
// half of an A2C run. This file is the same games, line for line:
//
//   - `Breakout::act` is breakout.py's `Env.act` (the paddle, the ball's diagonal move, its
//     reflections off the walls, the bricks and the paddle, the brick refill when the wall is
//     cleared, the end when the ball passes the paddle);
//   - `SpaceInvaders::act` is space_invaders.py's `Env.act` (the cannon, its cool-down, the
//     friendly bullets rolled up and the enemy bullets down, the aliens' march with its wrap
//     around (np.roll), the nearest alien's shot, the kills, the timers, the new wave and the
//     difficulty ramp);
//   - `Freeway::act` is freeway.py's (the chicken's move timer, the crossing that redraws the
//     cars, the cars' hits before and after they move, their wrap, the clock);
//   - `Asterix::act` is asterix.py's (the spawn into a random free slot, gold taken and enemies
//     met before and after the entities move, entities leaving the board, the speed ramp);
//   - `Seaquest::act` is seaquest.py's, with its Python lists of objects kept as lists
//     (`ObjectList`): the loops that remove while they iterate (`reversed`, `list.remove` of the
//     first equal element, an object mutated and still shooting after its removal) do here
//     what they do in Python;
//   - the sticky action is `Environment.act`'s: one uniform draw per primitive step from the
//     game's own `np.random.RandomState`, through numpy's `bitgen_t` (the same `next_double` that
//     `RandomState.rand()` calls, so the game's random stream is shared with Python, draw for
//     draw); `RandomState.randint(n)` is numpy's masked bounded integer (`next_uint32()` and
//     the smallest all-ones mask over n - 1, redrawn while above n - 1; no draw for n = 1): the
//     Breakout serve's `randint(2)`, Freeway's `randint(1, 6, 8)`, Asterix's slot, Seaquest's
//     lane;
//     `rand()` is `next_double()`;
//   - `write_state` is `Env.state()` written straight into the agent's channels-first float32
//     view.
//
// `tests/test_minatar_vector.py` compares every output with the Python path on fixed seeds and
// actions, and single steps from arbitrary game states (Breakout's brick refill, Space
// Invaders' new waves, Freeway's crossings, Asterix's spawns, Seaquest's surfacing and equal
// objects, the ramps), comparing the games' variables and their generators' states too.
//
// Python checks every argument (shapes, dtypes, contiguity, actions in range); this file checks
// buffer sizes again so that a wrong call is an error, never a write outside an array.

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <string>

#include "_pybuffers.h"

namespace {

// numpy/random/bitgen.h: the bit generator interface behind `RandomState._bit_generator`.
struct BitGen {
  void* state;
  uint64_t (*next_uint64)(void* st);
  uint32_t (*next_uint32)(void* st);
  double (*next_double)(void* st);
  uint64_t (*next_raw)(void* st);
};

constexpr int kSize = 10;                       // the 10×10 board
constexpr int kCells = kSize * kSize;
constexpr int kLeft = 1, kUp = 2, kRight = 3, kDown = 4, kFire = 5;  // n l u r d f

// ---- Breakout ----------------------------------------------------------------------------------

struct Breakout {
  // One game's variables, in the order of a row of the int32 `core` array; its map: the bricks.
  enum Field { kBallX, kBallY, kBallDir, kPos, kStrike, kLastX, kLastY, kLastAction, kFields };
  static constexpr int kMaps = 1;
  static constexpr int kChannels = 4;  // paddle, ball, trail, brick
  static constexpr const char* kInvalid =
      "is not a Breakout state (a position off the 10x10 board, a direction outside 0-3 or an "
      "action outside 0-5)";
  static constexpr const char* kActError =
      "the ball left the board at the bottom without ending the episode (a state no reset "
      "leads to)";

  static constexpr int kBounceX[4] = {1, 0, 3, 2};       // off a side wall
  static constexpr int kBounceY[4] = {3, 2, 1, 0};       // off the top, a brick or the paddle
  static constexpr int kBouncePaddle[4] = {2, 3, 0, 1};  // off the paddle's edge

  // Whether a game's variables are a state `Env.act` can step from: every position on the
  // board, a direction, a strike flag and a last action of MinAtar's six (a game edited by hand
  // could hold anything; stepping it would read and write outside the board).
  static bool valid(const int32_t* g) {
    for (int f : {kBallX, kBallY, kPos, kLastX, kLastY}) {
      if (g[f] < 0 || g[f] > 9) return false;
    }
    return g[kBallDir] >= 0 && g[kBallDir] <= 3 && (g[kStrike] == 0 || g[kStrike] == 1) &&
           g[kLastAction] >= 0 && g[kLastAction] <= 5;
  }

  // `Env.act(a)`: returns the reward; sets `*failed` where MinAtar's `act` raises IndexError (a
  // ball in the bottom row moving down, which no game played from a reset reaches) and
  // `*terminal` when the ball passed the paddle.
  static int act(int32_t* g, uint8_t* bricks, int64_t a, bool* terminal, BitGen*,
                 bool* failed) {
    int reward = 0;
    if (a == kLeft) {
      g[kPos] = g[kPos] > 0 ? g[kPos] - 1 : 0;
    } else if (a == kRight) {
      g[kPos] = g[kPos] < 9 ? g[kPos] + 1 : 9;
    }
    g[kLastX] = g[kBallX];
    g[kLastY] = g[kBallY];
    int dir = g[kBallDir];
    int new_x = g[kBallX] + ((dir == 0 || dir == 3) ? -1 : 1);
    int new_y = g[kBallY] + ((dir == 0 || dir == 1) ? -1 : 1);

    if (new_y > 9) {
      *failed = true;
      return 0;
    }
    bool strike_toggle = false;
    if (new_x < 0 || new_x > 9) {
      new_x = new_x < 0 ? 0 : 9;
      dir = kBounceX[dir];
    }
    if (new_y < 0) {
      new_y = 0;
      dir = kBounceY[dir];
    } else if (bricks[new_y * kSize + new_x] == 1) {
      strike_toggle = true;
      if (!g[kStrike]) {
        reward += 1;
        g[kStrike] = 1;
        bricks[new_y * kSize + new_x] = 0;
        new_y = g[kLastY];
        dir = kBounceY[dir];
      }
    } else if (new_y == 9) {
      bool cleared = true;
      for (int c = 0; c < kCells; ++c) {
        if (bricks[c] != 0) {
          cleared = false;
          break;
        }
      }
      if (cleared) {
        for (int c = kSize; c < 4 * kSize; ++c) bricks[c] = 1;  // rows 1..3
      }
      if (g[kBallX] == g[kPos]) {
        dir = kBounceY[dir];
        new_y = g[kLastY];
      } else if (new_x == g[kPos]) {
        dir = kBouncePaddle[dir];
        new_y = g[kLastY];
      } else {
        *terminal = true;
      }
    }
    if (!strike_toggle) g[kStrike] = 0;
    g[kBallDir] = dir;
    g[kBallX] = new_x;
    g[kBallY] = new_y;
    return reward;
  }

  // `Env.reset()` after `Environment.last_action = 0` (what `MinAtarEnv.reset()` does).
  static void reset(int32_t* g, uint8_t* bricks, BitGen* rng) {
    const bool right = (rng->next_uint32(rng->state) & 1u) != 0;  // RandomState.randint(2)
    g[kBallY] = 3;
    g[kBallX] = right ? 9 : 0;
    g[kBallDir] = right ? 3 : 2;
    g[kPos] = 4;
    std::memset(bricks, 0, kCells);
    std::memset(bricks + kSize, 1, 3 * kSize);
    g[kStrike] = 0;
    g[kLastX] = g[kBallX];
    g[kLastY] = g[kBallY];
    g[kLastAction] = 0;
  }

  // `Env.state()` as the agent's (channel, row, column) float32 frame.
  static void write_state(const int32_t* g, const uint8_t* bricks, float* out) {
    std::memset(out, 0, sizeof(float) * kChannels * kCells);
    out[0 * kCells + 9 * kSize + g[kPos]] = 1.0f;
    out[1 * kCells + g[kBallY] * kSize + g[kBallX]] = 1.0f;
    out[2 * kCells + g[kLastY] * kSize + g[kLastX]] = 1.0f;
    float* brick_channel = out + 3 * kCells;
    for (int c = 0; c < kCells; ++c) brick_channel[c] = bricks[c] ? 1.0f : 0.0f;
  }
};

// ---- Space Invaders ----------------------------------------------------------------------------

struct SpaceInvaders {
  // One game's variables (`terminal` and `ramping` as 0/1); its maps, each 10×10 of 0/1: the
  // aliens, the friendly bullets, the enemy bullets.
  enum Field { kPos, kAlienDir, kMoveInterval, kMoveTimer, kShotTimer, kRampIndex, kCoolDown,
               kTerminal, kRamping, kLastAction, kFields };
  static constexpr int kMaps = 3;
  static constexpr int kChannels = 6;  // cannon, alien, alien_left, alien_right, bullets (f, e)
  static constexpr const char* kInvalid =
      "is not a Space Invaders state (the cannon off the 10x10 board, a flag other than 0 or 1 "
      "or an action outside 0-5)";
  static constexpr const char* kActError =
      "an alien was to shoot but there is none (a state no reset leads to)";
  static constexpr int kShotCoolDown = 5, kEnemyMoveInterval = 12, kEnemyShotInterval = 10;

  static bool valid(const int32_t* g) {
    return g[kPos] >= 0 && g[kPos] <= 9 && (g[kTerminal] == 0 || g[kTerminal] == 1) &&
           (g[kRamping] == 0 || g[kRamping] == 1) && g[kLastAction] >= 0 &&
           g[kLastAction] <= 5;
  }

  static int count(const uint8_t* map) {
    int n = 0;
    for (int c = 0; c < kCells; ++c) n += map[c];
    return n;
  }

  static bool any_in_column(const uint8_t* map, int col) {
    for (int r = 0; r < kSize; ++r) {
      if (map[r * kSize + col]) return true;
    }
    return false;
  }

  // np.roll(map, shift, axis=0): row r takes row (r - shift) mod 10.
  static void roll_rows(uint8_t* map, int shift) {
    uint8_t old[kCells];
    std::memcpy(old, map, kCells);
    for (int r = 0; r < kSize; ++r) {
      const int from = ((r - shift) % kSize + kSize) % kSize;
      std::memcpy(map + r * kSize, old + from * kSize, kSize);
    }
  }

  // np.roll(map, shift, axis=1): column c takes column (c - shift) mod 10.
  static void roll_columns(uint8_t* map, int shift) {
    uint8_t old[kCells];
    std::memcpy(old, map, kCells);
    const int s = ((shift % kSize) + kSize) % kSize;
    for (int r = 0; r < kSize; ++r) {
      for (int c = 0; c < kSize; ++c) map[r * kSize + c] = old[r * kSize + (c - s + kSize) % kSize];
    }
  }

  // `Env.act(a)`: returns the reward (the aliens shot this step); sets `*failed` where MinAtar's
  // `act` raises TypeError (an alien shot due with no alien left, which no game played from a
  // reset reaches) and `*terminal` when an alien or an enemy bullet reached the cannon.
  static int act(int32_t* g, uint8_t* maps, int64_t a, bool* terminal, BitGen*,
                 bool* failed) {
    uint8_t* alien = maps;
    uint8_t* f_bullet = maps + kCells;
    uint8_t* e_bullet = maps + 2 * kCells;
    if (g[kTerminal]) {
      *terminal = true;
      return 0;
    }
    int& pos = g[kPos];
    if (a == kFire && g[kCoolDown] == 0) {
      f_bullet[9 * kSize + pos] = 1;
      g[kCoolDown] = kShotCoolDown;
    } else if (a == kLeft) {
      pos = pos > 0 ? pos - 1 : 0;
    } else if (a == kRight) {
      pos = pos < 9 ? pos + 1 : 9;
    }
    // Friendly bullets up, enemy bullets down (np.roll, then the wrapped row cleared).
    roll_rows(f_bullet, -1);
    std::memset(f_bullet + 9 * kSize, 0, kSize);
    roll_rows(e_bullet, 1);
    std::memset(e_bullet, 0, kSize);
    if (e_bullet[9 * kSize + pos]) g[kTerminal] = 1;

    if (alien[9 * kSize + pos]) g[kTerminal] = 1;
    if (g[kMoveTimer] == 0) {
      const int n = count(alien);
      g[kMoveTimer] = n < g[kMoveInterval] ? n : g[kMoveInterval];
      const int dir = g[kAlienDir];
      if ((any_in_column(alien, 0) && dir < 0) || (any_in_column(alien, 9) && dir > 0)) {
        g[kAlienDir] = -dir;
        bool bottom = false;
        for (int c = 0; c < kSize; ++c) bottom = bottom || alien[9 * kSize + c];
        if (bottom) g[kTerminal] = 1;
        roll_rows(alien, 1);
      } else {
        roll_columns(alien, dir);
      }
      if (alien[9 * kSize + pos]) g[kTerminal] = 1;
    }
    if (g[kShotTimer] == 0) {
      g[kShotTimer] = kEnemyShotInterval;
      // `_nearest_alien`: the columns by distance to the cannon (a stable sort: the left one
      // first on a tie), the lowest alien of the first column that has one.
      int shooter = -1;
      for (int d = 0; d < kSize && shooter < 0; ++d) {
        for (int col : {pos - d, pos + d}) {
          if (col < 0 || col > 9 || (d == 0 && col != pos) || shooter >= 0) continue;
          for (int r = kSize - 1; r >= 0; --r) {
            if (alien[r * kSize + col]) {
              shooter = r * kSize + col;
              break;
            }
          }
        }
      }
      if (shooter < 0) {
        *failed = true;
        return 0;
      }
      e_bullet[shooter] = 1;
    }
    int reward = 0;
    for (int c = 0; c < kCells; ++c) {
      if (alien[c] && f_bullet[c]) {
        ++reward;
        alien[c] = f_bullet[c] = 0;
      }
    }
    g[kCoolDown] -= g[kCoolDown] > 0;
    g[kMoveTimer] -= 1;
    g[kShotTimer] -= 1;
    if (count(alien) == 0) {
      if (g[kMoveInterval] > 6 && g[kRamping]) {
        g[kMoveInterval] -= 1;
        g[kRampIndex] += 1;
      }
      for (int r = 0; r < 4; ++r) std::memset(alien + r * kSize + 2, 1, 6);
    }
    *terminal = g[kTerminal] != 0;
    return reward;
  }

  // `Env.reset()` after `Environment.last_action = 0`; it draws nothing.
  static void reset(int32_t* g, uint8_t* maps, BitGen*) {
    g[kPos] = 5;
    std::memset(maps, 0, kMaps * kCells);
    for (int r = 0; r < 4; ++r) std::memset(maps + r * kSize + 2, 1, 6);
    g[kAlienDir] = -1;
    g[kMoveInterval] = kEnemyMoveInterval;
    g[kMoveTimer] = kEnemyMoveInterval;
    g[kShotTimer] = kEnemyShotInterval;
    g[kRampIndex] = 0;
    g[kCoolDown] = 0;
    g[kTerminal] = 0;
    g[kLastAction] = 0;
  }

  static void write_state(const int32_t* g, const uint8_t* maps, float* out) {
    std::memset(out, 0, sizeof(float) * kChannels * kCells);
    out[0 * kCells + 9 * kSize + g[kPos]] = 1.0f;
    const uint8_t* alien = maps;
    float* direction = out + (g[kAlienDir] < 0 ? 2 : 3) * kCells;
    for (int c = 0; c < kCells; ++c) {
      out[1 * kCells + c] = alien[c];
      direction[c] = alien[c];
      out[4 * kCells + c] = maps[kCells + c];
      out[5 * kCells + c] = maps[2 * kCells + c];
    }
  }
};

// ---- Freeway ----------------------------------------------------------------------------------

struct Freeway {
  // One game's variables, then its 8 cars' [x, y, timer, speed] (speed signed by direction),
  // then the last action; no maps.
  enum Field { kPos, kMoveTimer, kTerminateTimer, kTerminal, kCars, kLastAction = kCars + 32,
               kFields };
  static constexpr int kMaps = 0;
  static constexpr int kChannels = 7;  // chicken, car, the trail of speed 1 to 5
  static constexpr const char* kInvalid =
      "is not a Freeway state (the chicken or a car off the 10x10 board, a car's speed outside "
      "1-5 either way, a flag other than 0 or 1 or an action outside 0-5)";
  static constexpr const char* kActError = "";  // its act cannot fail
  static constexpr int kPlayerSpeed = 3, kTimeLimit = 2500;

  static bool valid(const int32_t* g) {
    if (g[kPos] < 0 || g[kPos] > 9 || (g[kTerminal] != 0 && g[kTerminal] != 1) ||
        g[kLastAction] < 0 || g[kLastAction] > 5) {
      return false;
    }
    for (int i = 0; i < 8; ++i) {
      const int32_t* car = g + kCars + 4 * i;
      const int speed = car[3] < 0 ? -car[3] : car[3];
      if (car[0] < 0 || car[0] > 9 || car[1] < 0 || car[1] > 9 || speed < 1 || speed > 5) {
        return false;
      }
    }
    return true;
  }

  // `_randomize_cars`: `randint(1, 6, 8)` (numpy's masked bounded integers: `next_uint32() & 7`
  // until at most 4, plus 1), then `sign(rand(8) - 0.5)`.
  static void randomize_cars(int32_t* g, BitGen* rng, bool initialize) {
    int32_t speeds[8];
    for (auto& speed : speeds) {
      uint32_t v;
      do {
        v = rng->next_uint32(rng->state) & 7u;
      } while (v > 4u);
      speed = static_cast<int32_t>(v) + 1;
    }
    for (auto& speed : speeds) {
      const double x = rng->next_double(rng->state) - 0.5;
      speed *= x > 0 ? 1 : (x < 0 ? -1 : 0);
    }
    for (int i = 0; i < 8; ++i) {
      int32_t* car = g + kCars + 4 * i;
      if (initialize) {
        car[0] = 0;
        car[1] = i + 1;
      }
      car[2] = speeds[i] < 0 ? -speeds[i] : speeds[i];
      car[3] = speeds[i];
    }
  }

  static int act(int32_t* g, uint8_t*, int64_t a, bool* terminal, BitGen* rng,
                 bool*) {  // it cannot fail
    if (g[kTerminal]) {
      *terminal = true;
      return 0;
    }
    int reward = 0;
    int& pos = g[kPos];
    if (a == kUp && g[kMoveTimer] == 0) {
      g[kMoveTimer] = kPlayerSpeed;
      pos = pos > 0 ? pos - 1 : 0;
    } else if (a == kDown && g[kMoveTimer] == 0) {
      g[kMoveTimer] = kPlayerSpeed;
      pos = pos < 9 ? pos + 1 : 9;
    }
    if (pos == 0) {
      reward += 1;
      randomize_cars(g, rng, false);
      pos = 9;
    }
    for (int i = 0; i < 8; ++i) {
      int32_t* car = g + kCars + 4 * i;
      if (car[0] == 4 && car[1] == pos) pos = 9;
      if (car[2] == 0) {
        car[2] = car[3] < 0 ? -car[3] : car[3];
        car[0] += car[3] > 0 ? 1 : -1;
        if (car[0] < 0) {
          car[0] = 9;
        } else if (car[0] > 9) {
          car[0] = 0;
        }
        if (car[0] == 4 && car[1] == pos) pos = 9;
      } else {
        car[2] -= 1;
      }
    }
    g[kMoveTimer] -= g[kMoveTimer] > 0;
    g[kTerminateTimer] -= 1;
    if (g[kTerminateTimer] < 0) g[kTerminal] = 1;
    *terminal = g[kTerminal] != 0;
    return reward;
  }

  static void reset(int32_t* g, uint8_t*, BitGen* rng) {
    randomize_cars(g, rng, true);
    g[kPos] = 9;
    g[kMoveTimer] = kPlayerSpeed;
    g[kTerminateTimer] = kTimeLimit;
    g[kTerminal] = 0;
    g[kLastAction] = 0;
  }

  static void write_state(const int32_t* g, const uint8_t*, float* out) {
    std::memset(out, 0, sizeof(float) * kChannels * kCells);
    out[0 * kCells + g[kPos] * kSize + 4] = 1.0f;
    int trail = -1;  // as in `state()`, a car of speed 0 (never drawn) keeps the last trail
    for (int i = 0; i < 8; ++i) {
      const int32_t* car = g + kCars + 4 * i;
      out[1 * kCells + car[1] * kSize + car[0]] = 1.0f;
      int back_x = car[3] > 0 ? car[0] - 1 : car[0] + 1;
      if (back_x < 0) {
        back_x = 9;
      } else if (back_x > 9) {
        back_x = 0;
      }
      const int speed = car[3] < 0 ? -car[3] : car[3];
      if (speed >= 1 && speed <= 5) trail = 1 + speed;
      if (trail >= 0) out[trail * kCells + car[1] * kSize + back_x] = 1.0f;
    }
  }
};

// ---- Asterix ----------------------------------------------------------------------------------

struct Asterix {
  // One game's variables, then its 8 entity slots' [present, x, y, moves right, gold], then the
  // last action; no maps.
  enum Field { kPlayerX, kPlayerY, kSpawnSpeed, kSpawnTimer, kMoveSpeed, kMoveTimer, kRampTimer,
               kRampIndex, kTerminal, kRamping, kEntities, kLastAction = kEntities + 40,
               kFields };
  static constexpr int kMaps = 0;
  static constexpr int kChannels = 4;  // player, enemy, trail, gold
  static constexpr const char* kInvalid =
      "is not an Asterix state (the player or an entity off the 10x10 board, a flag other than "
      "0 or 1 or an action outside 0-5)";
  static constexpr const char* kActError = "";  // its act cannot fail
  static constexpr int kRampInterval = 100;

  static bool valid(const int32_t* g) {
    if (g[kPlayerX] < 0 || g[kPlayerX] > 9 || g[kPlayerY] < 0 || g[kPlayerY] > 9 ||
        (g[kTerminal] != 0 && g[kTerminal] != 1) || (g[kRamping] != 0 && g[kRamping] != 1) ||
        g[kLastAction] < 0 || g[kLastAction] > 5) {
      return false;
    }
    for (int i = 0; i < 8; ++i) {
      const int32_t* e = g + kEntities + 5 * i;
      if ((e[0] != 0 && e[0] != 1) || (e[3] != 0 && e[3] != 1) || (e[4] != 0 && e[4] != 1)) {
        return false;
      }
      if (e[0] && (e[1] < 0 || e[1] > 9 || e[2] < 0 || e[2] > 9)) return false;
    }
    return true;
  }

  // `RandomState.randint(n)`: no draw for n = 1; else numpy's masked bounded integers.
  static int randint(BitGen* rng, int n) {
    const uint32_t range = static_cast<uint32_t>(n - 1);
    if (range == 0) return 0;
    uint32_t mask = range;
    for (int shift = 1; shift < 32; shift <<= 1) mask |= mask >> shift;
    uint32_t v;
    do {
      v = rng->next_uint32(rng->state) & mask;
    } while (v > range);
    return static_cast<int>(v);
  }

  // `_spawn_entity`.
  static void spawn(int32_t* g, BitGen* rng) {
    const bool lr = rng->next_double(rng->state) < 1.0 / 2;
    const bool gold = rng->next_double(rng->state) < 1.0 / 3;
    int slots[8];
    int n = 0;
    for (int i = 0; i < 8; ++i) {
      if (!g[kEntities + 5 * i]) slots[n++] = i;
    }
    if (n == 0) return;
    const int slot = slots[randint(rng, n)];
    int32_t* e = g + kEntities + 5 * slot;
    e[0] = 1;
    e[1] = lr ? 0 : 9;
    e[2] = slot + 1;
    e[3] = lr;
    e[4] = gold;
  }

  // An entity on the player: gold is taken (+1), an enemy ends the game.
  static void meet(int32_t* g, int32_t* e, int* reward) {
    if (e[1] == g[kPlayerX] && e[2] == g[kPlayerY]) {
      if (e[4]) {
        std::memset(e, 0, sizeof(int32_t) * 5);  // the slot is None again
        *reward += 1;
      } else {
        g[kTerminal] = 1;
      }
    }
  }

  static int act(int32_t* g, uint8_t*, int64_t a, bool* terminal, BitGen* rng,
                 bool*) {  // it cannot fail
    if (g[kTerminal]) {
      *terminal = true;
      return 0;
    }
    int reward = 0;
    if (g[kSpawnTimer] == 0) {
      spawn(g, rng);
      g[kSpawnTimer] = g[kSpawnSpeed];
    }
    if (a == kLeft) {
      g[kPlayerX] = g[kPlayerX] > 0 ? g[kPlayerX] - 1 : 0;
    } else if (a == kRight) {
      g[kPlayerX] = g[kPlayerX] < 9 ? g[kPlayerX] + 1 : 9;
    } else if (a == kUp) {
      g[kPlayerY] = g[kPlayerY] > 1 ? g[kPlayerY] - 1 : 1;
    } else if (a == kDown) {
      g[kPlayerY] = g[kPlayerY] < 8 ? g[kPlayerY] + 1 : 8;
    }
    for (int i = 0; i < 8; ++i) {
      int32_t* e = g + kEntities + 5 * i;
      if (e[0]) meet(g, e, &reward);
    }
    if (g[kMoveTimer] == 0) {
      g[kMoveTimer] = g[kMoveSpeed];
      for (int i = 0; i < 8; ++i) {
        int32_t* e = g + kEntities + 5 * i;
        if (!e[0]) continue;
        e[1] += e[3] ? 1 : -1;
        if (e[1] < 0 || e[1] > 9) {
          std::memset(e, 0, sizeof(int32_t) * 5);  // off the board: it can meet no one
        } else {
          meet(g, e, &reward);
        }
      }
    }
    g[kSpawnTimer] -= 1;
    g[kMoveTimer] -= 1;
    if (g[kRamping] && (g[kSpawnSpeed] > 1 || g[kMoveSpeed] > 1)) {
      if (g[kRampTimer] >= 0) {
        g[kRampTimer] -= 1;
      } else {
        if (g[kMoveSpeed] > 1 && g[kRampIndex] % 2) g[kMoveSpeed] -= 1;
        if (g[kSpawnSpeed] > 1) g[kSpawnSpeed] -= 1;
        g[kRampIndex] += 1;
        g[kRampTimer] = kRampInterval;
      }
    }
    *terminal = g[kTerminal] != 0;
    return reward;
  }

  static void reset(int32_t* g, uint8_t*, BitGen*) {
    g[kPlayerX] = 5;
    g[kPlayerY] = 5;
    std::memset(g + kEntities, 0, sizeof(int32_t) * 40);
    g[kSpawnSpeed] = 10;
    g[kSpawnTimer] = 10;
    g[kMoveSpeed] = 5;
    g[kMoveTimer] = 5;
    g[kRampTimer] = kRampInterval;
    g[kRampIndex] = 0;
    g[kTerminal] = 0;
    g[kLastAction] = 0;
  }

  static void write_state(const int32_t* g, const uint8_t*, float* out) {
    std::memset(out, 0, sizeof(float) * kChannels * kCells);
    out[0 * kCells + g[kPlayerY] * kSize + g[kPlayerX]] = 1.0f;
    for (int i = 0; i < 8; ++i) {
      const int32_t* e = g + kEntities + 5 * i;
      if (!e[0]) continue;
      out[(e[4] ? 3 : 1) * kCells + e[2] * kSize + e[1]] = 1.0f;
      const int back_x = e[3] ? e[1] - 1 : e[1] + 1;
      if (back_x >= 0 && back_x <= 9) out[2 * kCells + e[2] * kSize + back_x] = 1.0f;
    }
  }
};

// ---- Seaquest ---------------------------------------------------------------------------------

// Python's floor division and modulo (the game's `//` and `%` on values that may be negative).
inline int floor_div(int a, int b) { return a / b - ((a % b != 0) && ((a < 0) != (b < 0))); }
inline int py_mod(int a, int b) { return a - b * floor_div(a, b); }

// One of Seaquest's Python lists of small lists (bullets, fish, subs, divers) in an int32 row:
// its length, then `kCap` records of [id, values...]. The ids stand for the Python objects: a
// loop's element is mutated where it is, even after `list.remove` took another element equal
// to it in value (which is what `remove` does: the first equal one), and a reversed loop goes
// on by index as CPython's reversed list iterator does, so the game's loops that remove while
// they iterate do here what they do in Python.
struct ObjectList {
  static constexpr int kCap = 48;
  int32_t* base;
  int width;  // values per record
  int count() const { return base[0]; }
  int32_t* record(int k) const { return base + 1 + k * (width + 1); }
  int32_t* values(int k) const { return record(k) + 1; }
  static constexpr int size(int width) { return 1 + kCap * (width + 1); }
  int index_of_id(int32_t id) const {
    for (int k = 0; k < count(); ++k) {
      if (record(k)[0] == id) return k;
    }
    return -1;
  }
  void remove_at(int k) {
    const int n = count();
    for (int j = k; j + 1 < n; ++j) std::memcpy(record(j), record(j + 1), 4 * (width + 1));
    std::memset(record(n - 1), 0, 4 * (width + 1));
    base[0] = n - 1;
  }
  // `list.remove(v)`: the first element equal to `v` in value.
  void remove_equal(const int32_t* v) {
    for (int k = 0; k < count(); ++k) {
      if (std::memcmp(values(k), v, 4 * width) == 0) {
        remove_at(k);
        return;
      }
    }
  }
  // `list += [v]`; false when the list is full (no game played from a reset gets there).
  bool append(const int32_t* v, int32_t* next_id) {
    if (count() >= kCap) return false;
    int32_t* r = record(count());
    r[0] = (*next_id)++;
    std::memcpy(r + 1, v, 4 * width);
    base[0] += 1;
    return true;
  }
};

// The element a loop holds: its values, written back to its record while it is in the list.
struct Held {
  ObjectList* list;
  int32_t id;
  int32_t v[6];
  Held(ObjectList* l, int k) : list(l), id(l->record(k)[0]) {
    std::memcpy(v, l->values(k), 4 * l->width);
  }
  void store() {
    const int k = list->index_of_id(id);
    if (k >= 0) std::memcpy(list->values(k), v, 4 * list->width);
  }
};

// Seaquest's row: 15 variables, its five lists (widths 3, 3, 4, 5, 4), the last action.
constexpr int kSeaquestLastAction =
    15 + 5 + ObjectList::kCap * ((3 + 1) + (3 + 1) + (4 + 1) + (5 + 1) + (4 + 1));

struct Seaquest {
  enum Field { kOxygen, kDiverCount, kSubX, kSubY, kSubOr, kSpawnSpeed, kSpawnTimer,
               kDiverTimer, kMoveSpeed, kRampIndex, kShotTimer, kSurface, kTerminal, kRamping,
               kNextId, kLists };
  // The lists, in the row's order, and their values per element.
  enum List { kFriendly, kEnemyBullets, kFish, kSubs, kDivers, kNumLists };
  static constexpr int kWidths[kNumLists] = {3, 3, 4, 5, 4};  // [x, y, dir, timers...]
  static constexpr int kLastAction = kSeaquestLastAction;
  static int list_offset(int which) {
    int offset = kLists;
    for (int j = 0; j < which; ++j) offset += ObjectList::size(kWidths[j]);
    return offset;
  }
  static constexpr int kFields = kLastAction + 1;
  static constexpr int kMaps = 0;
  static constexpr int kChannels = 10;
  static constexpr const char* kInvalid =
      "is not a Seaquest state (the submarine or an object off the 10x10 board, the submarine "
      "in the right column facing left, a list longer than 48, a flag other than 0 or 1 or an "
      "action outside 0-5)";
  static constexpr const char* kActError =
      "more than 48 objects of one kind (a state no reset leads to)";
  static constexpr int kMaxOxygen = 200, kDiverSpawnSpeed = 30, kShotCoolDown = 5,
                       kEnemyShotInterval = 10, kDiverMoveInterval = 5;

  static ObjectList list(int32_t* g, int which) {
    return ObjectList{g + list_offset(which), kWidths[which]};
  }

  static bool valid(const int32_t* g) {
    if (g[kSubX] < 0 || g[kSubX] > 9 || g[kSubY] < 0 || g[kSubY] > 9 ||
        (g[kSubX] == 9 && !g[kSubOr]) || g[kLastAction] < 0 || g[kLastAction] > 5) {
      return false;
    }
    for (int f : {kSubOr, kSurface, kTerminal, kRamping}) {
      if (g[f] != 0 && g[f] != 1) return false;
    }
    for (int which = 0; which < kNumLists; ++which) {
      const ObjectList l = list(const_cast<int32_t*>(g), which);
      if (l.count() < 0 || l.count() > ObjectList::kCap) return false;
      for (int k = 0; k < l.count(); ++k) {
        const int32_t* v = l.values(k);
        if (v[0] < 0 || v[0] > 9 || v[1] < 0 || v[1] > 9 || (v[2] != 0 && v[2] != 1)) {
          return false;
        }
      }
    }
    return true;
  }

  static bool at_sub(const int32_t* g, const int32_t* v) {
    return v[0] == g[kSubX] && v[1] == g[kSubY];
  }

  // `randint(low=1, high=9)`: range 7, mask 7, so one draw.
  static int32_t row(BitGen* rng) {
    return static_cast<int32_t>(rng->next_uint32(rng->state) & 7u) + 1;
  }

  static bool spawn_enemy(int32_t* g, BitGen* rng) {
    const int32_t lr = rng->next_double(rng->state) < 1.0 / 2;
    const bool is_sub = rng->next_double(rng->state) < 1.0 / 3;
    const int32_t x = lr ? 0 : 9;
    const int32_t y = row(rng);
    for (int which : {kSubs, kFish}) {
      const ObjectList l = list(g, which);
      for (int k = 0; k < l.count(); ++k) {
        if (l.values(k)[1] == y && l.values(k)[2] != lr) return true;
      }
    }
    if (is_sub) {
      const int32_t v[5] = {x, y, lr, g[kMoveSpeed], kEnemyShotInterval};
      ObjectList subs = list(g, kSubs);
      return subs.append(v, &g[kNextId]);
    }
    const int32_t v[4] = {x, y, lr, g[kMoveSpeed]};
    ObjectList fish = list(g, kFish);
    return fish.append(v, &g[kNextId]);
  }

  static bool spawn_diver(int32_t* g, BitGen* rng) {
    const int32_t lr = rng->next_double(rng->state) < 1.0 / 2;
    const int32_t v[4] = {lr ? 0 : 9, row(rng), lr, kDiverMoveInterval};
    ObjectList divers = list(g, kDivers);
    return divers.append(v, &g[kNextId]);
  }

  // A friendly bullet meeting an object of `targets` (`for x in targets: ... break`).
  static bool shoot_first(ObjectList* targets, ObjectList* bullets, const int32_t* bullet,
                          int* reward) {
    for (int k = 0; k < targets->count(); ++k) {
      if (targets->values(k)[0] == bullet[0] && targets->values(k)[1] == bullet[1]) {
        int32_t hit[6];
        std::memcpy(hit, targets->values(k), 4 * targets->width);
        targets->remove_equal(hit);
        bullets->remove_equal(bullet);
        *reward += 1;
        return true;
      }
    }
    return false;
  }

  // An enemy that moved onto a friendly bullet (`for x in self.f_bullets: ... break`).
  static void meet_bullet(ObjectList* enemies, ObjectList* bullets, const int32_t* enemy,
                          int* reward) {
    for (int k = 0; k < bullets->count(); ++k) {
      if (enemy[0] == bullets->values(k)[0] && enemy[1] == bullets->values(k)[1]) {
        int32_t hit[3];
        std::memcpy(hit, bullets->values(k), 12);
        enemies->remove_equal(enemy);
        bullets->remove_equal(hit);
        *reward += 1;
        return;
      }
    }
  }

  // The march of an enemy sub or fish, the same in both loops: the submarine met where it is,
  // a move when its timer is due (off the board, onto the submarine, or onto a friendly
  // bullet, which both lose), the timer counted down otherwise.
  static void march(int32_t* g, ObjectList* enemies, ObjectList* friendly, Held* enemy,
                    int* reward) {
    int32_t* v = enemy->v;
    if (at_sub(g, v)) g[kTerminal] = 1;
    if (v[3] == 0) {
      v[3] = g[kMoveSpeed];
      v[0] += v[2] ? 1 : -1;
      enemy->store();
      if (v[0] < 0 || v[0] > 9) {
        enemies->remove_equal(v);
      } else if (at_sub(g, v)) {
        g[kTerminal] = 1;
      } else {
        meet_bullet(enemies, friendly, v, reward);
      }
    } else {
      v[3] -= 1;
      enemy->store();
    }
  }

  static int fail(bool* failed) {
    *failed = true;
    return 0;
  }

  static int surface(int32_t* g) {
    g[kSurface] = 1;
    int reward = 0;
    if (g[kDiverCount] == 6) {
      g[kDiverCount] = 0;
      reward = floor_div(g[kOxygen] * 10, kMaxOxygen);
    }
    g[kOxygen] = kMaxOxygen;
    g[kDiverCount] -= 1;
    if (g[kRamping] && (g[kSpawnSpeed] > 1 || g[kMoveSpeed] > 2)) {
      if (g[kMoveSpeed] > 2 && py_mod(g[kRampIndex], 2)) g[kMoveSpeed] -= 1;
      if (g[kSpawnSpeed] > 1) g[kSpawnSpeed] -= 1;
      g[kRampIndex] += 1;
    }
    return reward;
  }

  static int act(int32_t* g, uint8_t*, int64_t a, bool* terminal, BitGen* rng,
                 bool* failed) {
    if (g[kTerminal]) {
      *terminal = true;
      return 0;
    }
    int reward = 0;
    ObjectList friendly = list(g, kFriendly), enemy_bullets = list(g, kEnemyBullets),
               fish = list(g, kFish), subs = list(g, kSubs), divers = list(g, kDivers);
    if (g[kSpawnTimer] == 0) {
      if (!spawn_enemy(g, rng)) return fail(failed);
      g[kSpawnTimer] = g[kSpawnSpeed];
    }
    if (g[kDiverTimer] == 0) {
      if (!spawn_diver(g, rng)) return fail(failed);
      g[kDiverTimer] = kDiverSpawnSpeed;
    }
    if (a == kFire && g[kShotTimer] == 0) {
      const int32_t v[3] = {g[kSubX], g[kSubY], g[kSubOr]};
      if (!friendly.append(v, &g[kNextId])) return fail(failed);
      g[kShotTimer] = kShotCoolDown;
    } else if (a == kLeft) {
      g[kSubX] = g[kSubX] > 0 ? g[kSubX] - 1 : 0;
      g[kSubOr] = 0;
    } else if (a == kRight) {
      g[kSubX] = g[kSubX] < 9 ? g[kSubX] + 1 : 9;
      g[kSubOr] = 1;
    } else if (a == kUp) {
      g[kSubY] = g[kSubY] > 0 ? g[kSubY] - 1 : 0;
    } else if (a == kDown) {
      g[kSubY] = g[kSubY] < 8 ? g[kSubY] + 1 : 8;
    }

    // Each loop below: `for obj in reversed(lst)`, CPython's way (by index, stopping once the
    // index is past the end).
    for (int i = friendly.count() - 1; i >= 0 && i < friendly.count(); --i) {
      Held bullet(&friendly, i);
      bullet.v[0] += bullet.v[2] ? 1 : -1;
      bullet.store();
      if (bullet.v[0] < 0 || bullet.v[0] > 9) {
        friendly.remove_equal(bullet.v);
      } else if (!shoot_first(&fish, &friendly, bullet.v, &reward)) {
        shoot_first(&subs, &friendly, bullet.v, &reward);
      }
    }

    for (int i = divers.count() - 1; i >= 0 && i < divers.count(); --i) {
      Held diver(&divers, i);
      if (at_sub(g, diver.v) && g[kDiverCount] < 6) {
        divers.remove_equal(diver.v);
        g[kDiverCount] += 1;
      } else if (diver.v[3] == 0) {
        diver.v[3] = kDiverMoveInterval;
        diver.v[0] += diver.v[2] ? 1 : -1;
        diver.store();
        if (diver.v[0] < 0 || diver.v[0] > 9) {
          divers.remove_equal(diver.v);
        } else if (at_sub(g, diver.v) && g[kDiverCount] < 6) {
          divers.remove_equal(diver.v);
          g[kDiverCount] += 1;
        }
      } else {
        diver.v[3] -= 1;
        diver.store();
      }
    }

    for (int i = subs.count() - 1; i >= 0 && i < subs.count(); --i) {
      Held sub(&subs, i);
      march(g, &subs, &friendly, &sub, &reward);
      // The sub shoots even when it was just removed (the Python object still exists).
      if (sub.v[4] == 0) {
        sub.v[4] = kEnemyShotInterval;
        sub.store();
        const int32_t shot[3] = {sub.v[0], sub.v[1], sub.v[2]};
        if (!enemy_bullets.append(shot, &g[kNextId])) return fail(failed);
      } else {
        sub.v[4] -= 1;
        sub.store();
      }
    }

    for (int i = enemy_bullets.count() - 1; i >= 0 && i < enemy_bullets.count(); --i) {
      Held bullet(&enemy_bullets, i);
      if (at_sub(g, bullet.v)) g[kTerminal] = 1;
      bullet.v[0] += bullet.v[2] ? 1 : -1;
      bullet.store();
      if (bullet.v[0] < 0 || bullet.v[0] > 9) {
        enemy_bullets.remove_equal(bullet.v);
      } else if (at_sub(g, bullet.v)) {
        g[kTerminal] = 1;
      }
    }

    for (int i = fish.count() - 1; i >= 0 && i < fish.count(); --i) {
      Held one(&fish, i);
      march(g, &fish, &friendly, &one, &reward);
    }

    g[kSpawnTimer] -= g[kSpawnTimer] > 0;
    g[kDiverTimer] -= g[kDiverTimer] > 0;
    g[kShotTimer] -= g[kShotTimer] > 0;
    if (g[kOxygen] <= 0) g[kTerminal] = 1;
    if (g[kSubY] > 0) {
      g[kOxygen] -= 1;
      g[kSurface] = 0;
    } else if (!g[kSurface]) {
      if (g[kDiverCount] == 0) {
        g[kTerminal] = 1;
      } else {
        reward += surface(g);
      }
    }
    *terminal = g[kTerminal] != 0;
    return reward;
  }

  static void reset(int32_t* g, uint8_t*, BitGen*) {
    const int32_t ramping = g[kRamping];  // a setting, not a variable the reset sets
    std::memset(g, 0, sizeof(int32_t) * kLastAction);
    g[kOxygen] = kMaxOxygen;
    g[kSubX] = 5;
    g[kSpawnSpeed] = 20;
    g[kSpawnTimer] = 20;
    g[kDiverTimer] = kDiverSpawnSpeed;
    g[kMoveSpeed] = 5;
    g[kSurface] = 1;
    g[kRamping] = ramping;
    g[kNextId] = 1;
    g[kLastAction] = 0;
  }

  static void mark(float* out, int channel, int y, int x) {
    out[channel * kCells + y * kSize + x] = 1.0f;
  }

  static void write_state(const int32_t* g, const uint8_t*, float* out) {
    std::memset(out, 0, sizeof(float) * kChannels * kCells);
    int32_t* row = const_cast<int32_t*>(g);
    mark(out, 0, g[kSubY], g[kSubX]);
    int back_x = g[kSubOr] ? g[kSubX] - 1 : g[kSubX] + 1;
    if (back_x < 0) back_x += kSize;  // numpy's negative index
    mark(out, 1, g[kSubY], back_x);
    const int oxygen = g[kOxygen] > 0 ? g[kOxygen] : 0;
    const int gauge = floor_div(oxygen * 10, kMaxOxygen);
    for (int c = 0; c < (gauge < kSize ? gauge : kSize); ++c) mark(out, 7, 9, c);
    int start = 9 - g[kDiverCount];  // the slice [9 - diver_count : 9]
    if (start < 0) start = start + kSize < 0 ? 0 : start + kSize;
    for (int c = start; c < 9; ++c) mark(out, 8, 9, c);
    const ObjectList friendly = list(row, kFriendly), enemy_bullets = list(row, kEnemyBullets);
    for (int k = 0; k < friendly.count(); ++k) {
      mark(out, 2, friendly.values(k)[1], friendly.values(k)[0]);
    }
    for (int k = 0; k < enemy_bullets.count(); ++k) {
      mark(out, 4, enemy_bullets.values(k)[1], enemy_bullets.values(k)[0]);
    }
    const int channels[3] = {5, 6, 9};  // fish, subs, divers; each with its trail
    const int lists[3] = {kFish, kSubs, kDivers};
    for (int j = 0; j < 3; ++j) {
      const ObjectList l = list(row, lists[j]);
      for (int k = 0; k < l.count(); ++k) {
        const int32_t* v = l.values(k);
        mark(out, channels[j], v[1], v[0]);
        const int back = v[2] ? v[0] - 1 : v[0] + 1;
        if (back >= 0 && back <= 9) mark(out, 3, v[1], back);
      }
    }
  }
};

using routine_gym::Buffers;

const char kStepArgs[] =
    "(core, maps, rngs, sticky, actions, sequences, sequence_lengths, elapsed, limit, rewards,\n"
    "    terminated, truncated, executed, step_rewards, inner_states, states, final_states,\n"
    "    returns, lengths, episode_returns, episode_lengths) -> int\n\n"
    "Step every game once: its primitive action or routine, stopping at the end of an episode\n"
    "(terminated, or truncated at `limit` steps, -1 for none), resetting a game whose episode\n"
    "ended; returns how many episodes ended. `returns` and `lengths` are each game's episode so\n"
    "far, grown by this step; a game whose episode ended writes them to `episode_returns` and\n"
    "`episode_lengths` (0 for the others) and starts again from 0, as `elapsed`. Every action\n"
    "is checked before any game moves. Arrays (C-contiguous, E games, A actions, L the longest\n"
    "sequence, F the game's fields, M its maps, C its channels): core int32 (E, F), maps uint8\n"
    "(E, M, 10, 10), rngs uint64 (E,) bitgen_t addresses, actions int64 (E,), sequences int64\n"
    "(A, L), sequence_lengths int64 (A,), elapsed int64 (E,), rewards float64 (E,), terminated\n"
    "and truncated bool (E,), executed int64 (E,), step_rewards float64 (E, L) or None,\n"
    "inner_states float32 (E, L, C, 10, 10) or None, states and final_states float32 (E, C, 10,\n"
    "10), returns and episode_returns float64 (E,), lengths and episode_lengths int64 (E,).\n"
    "Breakout: F 8, M 1 (bricks), C 4; Space Invaders: F 10, M 3 (aliens, friendly bullets,\n"
    "enemy bullets), C 6; Freeway: F 37 (4 variables, 8 cars of 4), M 0, C 7; Asterix: F 51 (10\n"
    "variables, 8 entity slots of 5), M 0, C 4; Seaquest: F 1173 (15 variables, 5 lists of up\n"
    "to 48 objects), M 0, C 10.";

template <typename Game>
PyObject* step_games(PyObject* args) {
  constexpr int kFields = Game::kFields;
  constexpr int kMapCells = Game::kMaps * kCells;
  constexpr int kFrame = Game::kChannels * kCells;  // floats per observation
  PyObject *core_o, *maps_o, *rngs_o, *actions_o, *sequences_o, *lengths_o, *elapsed_o;
  PyObject *rewards_o, *terminated_o, *truncated_o, *executed_o, *step_rewards_o, *inner_o;
  PyObject *states_o, *final_o, *returns_o, *episode_lengths_o, *episode_returns_o;
  PyObject* sofar_o;
  double sticky;
  long long limit;
  if (!PyArg_ParseTuple(args, "OOOdOOOOLOOOOOOOOOOOO", &core_o, &maps_o, &rngs_o, &sticky,
                        &actions_o, &sequences_o, &lengths_o, &elapsed_o, &limit, &rewards_o,
                        &terminated_o, &truncated_o, &executed_o, &step_rewards_o, &inner_o,
                        &states_o, &final_o, &returns_o, &sofar_o, &episode_returns_o,
                        &episode_lengths_o)) {
    return nullptr;
  }
  Buffers b;
  // The sizes that fix E, A and L (views 0, 1 and 2).
  const Py_ssize_t e = b.count_of<int64_t>(actions_o, "actions");
  if (e < 0) return nullptr;
  const Py_ssize_t num_actions = b.count_of<int64_t>(lengths_o, "sequence_lengths");
  if (num_actions < 0) return nullptr;
  const Py_ssize_t seq_items = b.count_of<int64_t>(sequences_o, "sequences");
  if (seq_items < 0) return nullptr;
  if (num_actions == 0 || seq_items % num_actions) {
    PyErr_SetString(PyExc_ValueError, "sequences must hold the same number of rows as "
                                      "sequence_lengths");
    return nullptr;
  }
  const Py_ssize_t max_len = seq_items / num_actions;
  const auto* actions = static_cast<const int64_t*>(b.views[0].buf);
  const auto* seq_lengths = static_cast<const int64_t*>(b.views[1].buf);
  const auto* sequences = static_cast<const int64_t*>(b.views[2].buf);

  auto* core = static_cast<int32_t*>(b.get(core_o, e * kFields * 4, true, "core"));
  if (!core) return nullptr;
  auto* maps = static_cast<uint8_t*>(b.get(maps_o, e * kMapCells, true, "maps"));
  if (!maps) return nullptr;
  auto* rngs = static_cast<const uint64_t*>(b.get(rngs_o, e * 8, false, "rngs"));
  if (!rngs) return nullptr;
  auto* elapsed = static_cast<int64_t*>(b.get(elapsed_o, e * 8, true, "elapsed"));
  if (!elapsed) return nullptr;
  auto* rewards = static_cast<double*>(b.get(rewards_o, e * 8, true, "rewards"));
  if (!rewards) return nullptr;
  auto* terminated = static_cast<bool*>(b.get(terminated_o, e, true, "terminated"));
  if (!terminated) return nullptr;
  auto* truncated = static_cast<bool*>(b.get(truncated_o, e, true, "truncated"));
  if (!truncated) return nullptr;
  auto* executed = static_cast<int64_t*>(b.get(executed_o, e * 8, true, "executed"));
  if (!executed) return nullptr;
  auto* step_rewards = static_cast<double*>(
      b.get(step_rewards_o, e * max_len * 8, true, "step_rewards", true));
  if (!step_rewards && PyErr_Occurred()) return nullptr;
  auto* inner = static_cast<float*>(
      b.get(inner_o, e * max_len * kFrame * 4, true, "inner_states", true));
  if (!inner && PyErr_Occurred()) return nullptr;
  auto* states = static_cast<float*>(b.get(states_o, e * kFrame * 4, true, "states"));
  if (!states) return nullptr;
  auto* final_states = static_cast<float*>(b.get(final_o, e * kFrame * 4, true,
                                                  "final_states"));
  if (!final_states) return nullptr;
  auto* returns = static_cast<double*>(b.get(returns_o, e * 8, true, "returns"));
  if (!returns) return nullptr;
  auto* sofar = static_cast<int64_t*>(b.get(sofar_o, e * 8, true, "lengths"));
  if (!sofar) return nullptr;
  auto* episode_returns = static_cast<double*>(b.get(episode_returns_o, e * 8, true,
                                                     "episode_returns"));
  if (!episode_returns) return nullptr;
  auto* episode_lengths = static_cast<int64_t*>(b.get(episode_lengths_o, e * 8, true,
                                                      "episode_lengths"));
  if (!episode_lengths) return nullptr;
  for (Py_ssize_t i = 0; i < e; ++i) {
    if (actions[i] < 0 || actions[i] >= num_actions) {
      PyErr_Format(PyExc_ValueError, "action %lld is outside [0, %zd)",
                   static_cast<long long>(actions[i]), num_actions);
      return nullptr;
    }
    const int64_t length = seq_lengths[actions[i]];
    if (length < 1 || length > max_len) {
      PyErr_SetString(PyExc_ValueError, "a sequence length is outside [1, L]");
      return nullptr;
    }
    if (rngs[i] == 0) {
      PyErr_SetString(PyExc_ValueError, "a game has no random number generator");
      return nullptr;
    }
    if (!Game::valid(core + i * kFields)) {
      PyErr_Format(PyExc_ValueError, "game %zd %s", i, Game::kInvalid);
      return nullptr;
    }
  }
  for (Py_ssize_t k = 0; k < max_len * num_actions; ++k) {
    if (sequences[k] < -1 || sequences[k] > 5) {
      PyErr_SetString(PyExc_ValueError, "a routine holds an action outside MinAtar's 0-5");
      return nullptr;
    }
  }

  Py_ssize_t ended = 0;
  for (Py_ssize_t i = 0; i < e; ++i) {
    int32_t* g = core + i * kFields;
    uint8_t* board = maps + i * kMapCells;
    auto* rng = reinterpret_cast<BitGen*>(static_cast<uintptr_t>(rngs[i]));
    const int64_t a = actions[i];
    const int64_t* sequence = sequences + a * max_len;
    double total = 0.0;
    bool term = false, trunc = false;
    int64_t k = 0;
    for (const int64_t length = seq_lengths[a]; k < length;) {
      int64_t primitive = sequence[k];
      if (rng->next_double(rng->state) < sticky) primitive = g[Game::kLastAction];
      g[Game::kLastAction] = static_cast<int32_t>(primitive);
      bool failed = false;
      const int reward = Game::act(g, board, primitive, &term, rng, &failed);
      if (failed) {
        PyErr_Format(PyExc_ValueError, "game %zd: %s", i, Game::kActError);
        return nullptr;
      }
      elapsed[i] += 1;
      trunc = limit >= 0 && elapsed[i] >= limit;
      total += reward;
      if (step_rewards) step_rewards[i * max_len + k] = reward;
      if (inner) Game::write_state(g, board, inner + (i * max_len + k) * kFrame);
      ++k;
      if (term || trunc) break;
    }
    rewards[i] = total;
    terminated[i] = term;
    truncated[i] = trunc;
    executed[i] = k;
    returns[i] += total;  // RecordEpisodeStatistics' sums
    sofar[i] += k;
    episode_returns[i] = 0.0;
    episode_lengths[i] = 0;
    if (term || trunc) {
      Game::write_state(g, board, final_states + i * kFrame);
      Game::reset(g, board, rng);
      elapsed[i] = 0;
      episode_returns[i] = returns[i];
      episode_lengths[i] = sofar[i];
      returns[i] = 0.0;
      sofar[i] = 0;
      ++ended;
    }
    Game::write_state(g, board, states + i * kFrame);
  }
  return PyLong_FromSsize_t(ended);
}

PyObject* breakout_step(PyObject*, PyObject* args) { return step_games<Breakout>(args); }
PyObject* space_invaders_step(PyObject*, PyObject* args) {
  return step_games<SpaceInvaders>(args);
}
PyObject* freeway_step(PyObject*, PyObject* args) { return step_games<Freeway>(args); }
PyObject* asterix_step(PyObject*, PyObject* args) { return step_games<Asterix>(args); }
PyObject* seaquest_step(PyObject*, PyObject* args) { return step_games<Seaquest>(args); }

const std::string kBreakoutDoc = std::string("breakout_step") + kStepArgs;
const std::string kSpaceInvadersDoc = std::string("space_invaders_step") + kStepArgs;
const std::string kFreewayDoc = std::string("freeway_step") + kStepArgs;
const std::string kAsterixDoc = std::string("asterix_step") + kStepArgs;
const std::string kSeaquestDoc = std::string("seaquest_step") + kStepArgs;

PyMethodDef kMethods[] = {
    {"breakout_step", breakout_step, METH_VARARGS, kBreakoutDoc.c_str()},
    {"space_invaders_step", space_invaders_step, METH_VARARGS, kSpaceInvadersDoc.c_str()},
    {"freeway_step", freeway_step, METH_VARARGS, kFreewayDoc.c_str()},
    {"asterix_step", asterix_step, METH_VARARGS, kAsterixDoc.c_str()},
    {"seaquest_step", seaquest_step, METH_VARARGS, kSeaquestDoc.c_str()},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef kModule = {
    PyModuleDef_HEAD_INIT, "routine_gym._native._minatar_core",
    "Compiled MinAtar games (all five) for routine_gym.envs.minatar_vector (see the source's "
    "header).",
    -1, kMethods, nullptr, nullptr, nullptr, nullptr,
};

}  // namespace

PyMODINIT_FUNC PyInit__minatar_core(void) { return PyModule_Create(&kModule); }
