// Compiled core of routine_gym.envs.minatar_vector for MinAtar's Breakout, Space Invaders,
// Freeway and Asterix: all games of a vector env stepped in one call, each through the primitive
// action or routine it was given (one C++ function, templated on the game).
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
//   - the sticky action is `Environment.act`'s: one uniform draw per primitive step from the
//     game's own `np.random.RandomState`, through numpy's `bitgen_t` (the same `next_double` that
//     `RandomState.rand()` calls, so the game's random stream is shared with Python, draw for
//     draw); `RandomState.randint(n)` is numpy's masked bounded integer (`next_uint32()` and
//     the smallest all-ones mask over n - 1, redrawn while above n - 1; no draw for n = 1): the
//     Breakout serve's `randint(2)`, Freeway's `randint(1, 6, 8)`, Asterix's slot;
//     `rand()` is `next_double()`;
//   - `write_state` is `Env.state()` written straight into the agent's channels-first float32
//     view.
//
// `tests/test_minatar_vector.py` compares every output with the Python path on fixed seeds and
// actions, and single steps from arbitrary game states (Breakout's brick refill, Space
// Invaders' new waves, Freeway's crossings, Asterix's spawns, the ramps), comparing the games'
// variables and their generators' states too.
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

  // `Env.act(a)`: returns the reward, or -1 where MinAtar's `act` raises IndexError (a ball in
  // the bottom row moving down, which no game played from a reset reaches); sets `*terminal`
  // when the ball passed the paddle.
  static int act(int32_t* g, uint8_t* bricks, int64_t a, bool* terminal, BitGen*) {
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

    if (new_y > 9) return -1;
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

  // `Env.act(a)`: returns the reward (the aliens shot this step), or -1 where MinAtar's `act`
  // raises TypeError (an alien shot due with no alien left, which no game played from a
  // reset reaches); sets `*terminal` when an alien or an enemy bullet reached the cannon.
  static int act(int32_t* g, uint8_t* maps, int64_t a, bool* terminal, BitGen*) {
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
      if (shooter < 0) return -1;
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

  static int act(int32_t* g, uint8_t*, int64_t a, bool* terminal, BitGen* rng) {
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

  static int act(int32_t* g, uint8_t*, int64_t a, bool* terminal, BitGen* rng) {
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

using routine_gym::Buffers;

const char kStepArgs[] =
    "(core, maps, rngs, sticky, actions, sequences, sequence_lengths, elapsed, limit, rewards,\n"
    "    terminated, truncated, executed, step_rewards, inner_states, states, final_states)\n\n"
    "Step every game once: its primitive action or routine, stopping at the end of an episode\n"
    "(terminated, or truncated at `limit` steps, -1 for none), resetting a game whose episode\n"
    "ended. Arrays (C-contiguous, E games, A actions, L the longest sequence, F the game's\n"
    "fields, M its maps, C its channels): core int32 (E, F), maps uint8 (E, M, 10, 10), rngs\n"
    "uint64 (E,) bitgen_t addresses, actions int64 (E,), sequences int64 (A, L),\n"
    "sequence_lengths int64 (A,), elapsed int64 (E,), rewards float64 (E,), terminated and\n"
    "truncated bool (E,), executed int64 (E,), step_rewards float64 (E, L) or None,\n"
    "inner_states float32 (E, L, C, 10, 10) or None, states and final_states float32\n"
    "(E, C, 10, 10). Breakout: F 8, M 1 (bricks), C 4; Space Invaders: F 10, M 3 (aliens,\n"
    "friendly bullets, enemy bullets), C 6; Freeway: F 37 (4 variables, 8 cars of 4), M 0, C 7;\n"
    "Asterix: F 51 (10 variables, 8 entity slots of 5), M 0, C 4.";

template <typename Game>
PyObject* step_games(PyObject* args) {
  constexpr int kFields = Game::kFields;
  constexpr int kMapCells = Game::kMaps * kCells;
  constexpr int kFrame = Game::kChannels * kCells;  // floats per observation
  PyObject *core_o, *maps_o, *rngs_o, *actions_o, *sequences_o, *lengths_o, *elapsed_o;
  PyObject *rewards_o, *terminated_o, *truncated_o, *executed_o, *step_rewards_o, *inner_o;
  PyObject *states_o, *final_o;
  double sticky;
  long long limit;
  if (!PyArg_ParseTuple(args, "OOOdOOOOLOOOOOOOO", &core_o, &maps_o, &rngs_o, &sticky,
                        &actions_o, &sequences_o, &lengths_o, &elapsed_o, &limit, &rewards_o,
                        &terminated_o, &truncated_o, &executed_o, &step_rewards_o, &inner_o,
                        &states_o, &final_o)) {
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
      const int reward = Game::act(g, board, primitive, &term, rng);
      if (reward < 0) {
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
    if (term || trunc) {
      Game::write_state(g, board, final_states + i * kFrame);
      Game::reset(g, board, rng);
      elapsed[i] = 0;
    }
    Game::write_state(g, board, states + i * kFrame);
  }
  Py_RETURN_NONE;
}

PyObject* breakout_step(PyObject*, PyObject* args) { return step_games<Breakout>(args); }
PyObject* space_invaders_step(PyObject*, PyObject* args) {
  return step_games<SpaceInvaders>(args);
}
PyObject* freeway_step(PyObject*, PyObject* args) { return step_games<Freeway>(args); }
PyObject* asterix_step(PyObject*, PyObject* args) { return step_games<Asterix>(args); }

const std::string kBreakoutDoc = std::string("breakout_step") + kStepArgs;
const std::string kSpaceInvadersDoc = std::string("space_invaders_step") + kStepArgs;
const std::string kFreewayDoc = std::string("freeway_step") + kStepArgs;
const std::string kAsterixDoc = std::string("asterix_step") + kStepArgs;

PyMethodDef kMethods[] = {
    {"breakout_step", breakout_step, METH_VARARGS, kBreakoutDoc.c_str()},
    {"space_invaders_step", space_invaders_step, METH_VARARGS, kSpaceInvadersDoc.c_str()},
    {"freeway_step", freeway_step, METH_VARARGS, kFreewayDoc.c_str()},
    {"asterix_step", asterix_step, METH_VARARGS, kAsterixDoc.c_str()},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef kModule = {
    PyModuleDef_HEAD_INIT, "_minatar_core",
    "Compiled MinAtar Breakout, Space Invaders, Freeway and Asterix for "
    "routine_gym.envs.minatar_vector (see the source's header).",
    -1, kMethods, nullptr, nullptr, nullptr, nullptr,
};

}  // namespace

PyMODINIT_FUNC PyInit__minatar_core(void) { return PyModule_Create(&kModule); }
