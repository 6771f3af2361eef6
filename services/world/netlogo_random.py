"""NetLogo's random stream: its Mersenne Twister and the way its primitives draw from it.

Written from NetLogo's source (org.nlogo.api.MersenneTwisterFast, the prims `random-seed`,
`random`, `random-float`, `one-of`, `n-of`, `shuffle`, `create-turtles`, and the agentset
"shufflerator" that `ask` and `of` iterate with); docs/netlogo-random.md says which calls the
SpikingLab source makes. Pure Python and exact, not fast: one draw is one 32-bit word of MT19937.

Java integer semantics matter here: NetLogo's words are signed ints, and `random N` goes
through nextLong, whose 64-bit word NetLogo before 7.0 built as `(y << 32) + z` with z
sign-extended (the published SpikingLab ran on those versions); 7.0 concatenates the bits.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import TypeVar

T = TypeVar("T")

_N, _M = 624, 397
_MATRIX_A = 0x9908B0DF
_UPPER, _LOWER = 0x80000000, 0x7FFFFFFF
_MASK32, _MASK64 = 0xFFFFFFFF, 0xFFFFFFFFFFFFFFFF
_INT_MIN, _INT_MAX = -(2**31), 2**31 - 1
BASE_COLOURS = 14  # create-turtles picks one of NetLogo's 14 base colours (5, 15, .., 135)


def _signed32(word: int) -> int:
    return word - (1 << 32) if word & _UPPER else word


class MersenneTwister:
    """MT19937 with NetLogo's seeding and its derived draws (next_int, next_long, next_double).

    `legacy_long`: build nextLong's 64-bit word as NetLogo up to 6.x did (True, the default) or
    as NetLogo 7.0 does (False); only `random N` (next_long) depends on it.
    """

    def __init__(self, seed: int = 0, legacy_long: bool = True) -> None:
        self.legacy_long = legacy_long
        self._mt = [0] * _N
        self._index = _N
        self.set_seed(seed)

    def set_seed(self, seed: int) -> None:
        """MT19937 init_genrand with the low 32 bits of `seed` (MersenneTwisterFast.setSeed)."""
        mt = self._mt
        mt[0] = seed & _MASK32
        for i in range(1, _N):
            prev = mt[i - 1]
            mt[i] = (1812433253 * (prev ^ (prev >> 30)) + i) & _MASK32
        self._index = _N

    def set_seed_array(self, key: Sequence[int]) -> None:
        """MT19937 init_by_array (MersenneTwisterFast.setSeed(int[]))."""
        self.set_seed(19650218)
        mt, i, j = self._mt, 1, 0
        for _ in range(max(_N, len(key))):
            prev = mt[i - 1]
            mt[i] = ((mt[i] ^ ((prev ^ (prev >> 30)) * 1664525)) + key[j] + j) & _MASK32
            i, j = i + 1, j + 1
            if i >= _N:
                mt[0], i = mt[_N - 1], 1
            if j >= len(key):
                j = 0
        for _ in range(_N - 1):
            prev = mt[i - 1]
            mt[i] = ((mt[i] ^ ((prev ^ (prev >> 30)) * 1566083941)) - i) & _MASK32
            i += 1
            if i >= _N:
                mt[0], i = mt[_N - 1], 1
        mt[0] = 0x80000000

    def _twist(self) -> None:
        mt = self._mt
        for k in range(_N):
            y = (mt[k] & _UPPER) | (mt[(k + 1) % _N] & _LOWER)
            mt[k] = mt[(k + _M) % _N] ^ (y >> 1) ^ (_MATRIX_A if y & 1 else 0)
        self._index = 0

    def next_word(self) -> int:
        """The next tempered 32-bit output, unsigned (Java's nextInt() is this as a signed int)."""
        if self._index >= _N:
            self._twist()
        y = self._mt[self._index]
        self._index += 1
        y ^= y >> 11
        y ^= (y << 7) & 0x9D2C5680
        y ^= (y << 15) & 0xEFC60000
        y ^= y >> 18
        return y & _MASK32

    def state(self) -> tuple[list[int], int]:
        """A copy of the generator's 624 words and the index of the next word to temper (624: the
        words are used up, the next draw twists them first), for compiled copies of the stream."""
        return list(self._mt), self._index

    def next_int(self, n: int) -> int:
        """Uniform in [0, n) from 31-bit draws, rejecting the uneven tail (nextInt(int))."""
        if n <= 0:
            raise ValueError(f"next_int needs n > 0, got {n}")
        if n & -n == n:  # a power of two: the top bits
            return (n * (self.next_word() >> 1)) >> 31
        while True:
            bits = self.next_word() >> 1
            value = bits % n
            if bits - value + (n - 1) <= _INT_MAX:  # Java: the int sum did not overflow
                return value

    def _next_word64(self) -> int:
        y, z = self.next_word(), self.next_word()
        if self.legacy_long:  # ((long) y << 32) + z, with both ints sign-extended
            return ((_signed32(y) << 32) + _signed32(z)) & _MASK64
        return (y << 32) | z

    def next_long(self, n: int) -> int:
        """Uniform in [0, n) from 63-bit draws (nextLong(long)); `random N` uses it."""
        if n <= 0:
            raise ValueError(f"next_long needs n > 0, got {n}")
        while True:
            bits = self._next_word64() >> 1
            value = bits % n
            if bits - value + (n - 1) < 2**63:  # Java: the long sum did not overflow
                return value

    def next_double(self) -> float:
        """Uniform in [0, 1) with 53 random bits (nextDouble)."""
        y, z = self.next_word(), self.next_word()
        return ((y >> 6) * (1 << 27) + (z >> 5)) / float(1 << 53)


class NetLogoRandom(MersenneTwister):
    """The primitives of NetLogo that draw, each drawing exactly as NetLogo's does."""

    def random_seed(self, seed: float) -> None:
        """`random-seed N`: N truncated to an integer, which must fit a Java int."""
        whole = math.trunc(seed)
        if not _INT_MIN <= whole <= _INT_MAX:
            raise ValueError(f"random seed {seed} is outside -2147483648 .. 2147483647")
        self.set_seed(whole)

    def random(self, limit: float) -> int:
        """`random N`: an integer in [0, N) (or (N, 0] for N < 0); a fractional N rounds away
        from zero first, and N = 0 draws nothing."""
        whole = math.trunc(limit)
        if limit != whole:
            whole += 1 if limit >= 0 else -1
        if whole > 0:
            return self.next_long(whole)
        if whole < 0:
            return -self.next_long(-whole)
        return 0

    def random_float(self, limit: float) -> float:
        """`random-float N`: N times one nextDouble."""
        return limit * self.next_double()

    def random_coordinate(self, min_patch: int, max_patch: int) -> float:
        """`random-xcor` / `random-ycor`: uniform over the patches' extent, edges included."""
        low, high = min_patch - 0.5, max_patch + 0.5
        return low + self.next_double() * (high - low)

    def one_of(self, items: Sequence[T]) -> T | None:
        """`one-of` a list or an agentset (in the agentset's own order); None for an empty one
        (NetLogo: an error for a list, nobody for an agentset), drawing nothing."""
        if not items:
            return None
        return items[self.next_int(len(items))]

    def n_of_list(self, n: float, items: Sequence[T]) -> list[T]:
        """`n-of N list`: N truncated; each item kept with probability (wanted left)/(items left)."""
        count = int(n)
        if count < 0 or count > len(items):
            raise ValueError(f"n-of {n}: needs 0 <= N <= {len(items)}")
        if count == len(items):
            return list(items)
        return self._subset(count, items)

    def n_of_agents(self, n: float, agents: Sequence[T]) -> list[T]:
        """`n-of N agentset`, in the agentset's order: one and two agents have their own draws."""
        count = int(n)
        if count < 0 or count > len(agents):
            raise ValueError(f"n-of {n}: needs 0 <= N <= {len(agents)}")
        size = len(agents)
        if count == 0:
            return []
        if count == 1:
            return [agents[self.next_int(size)]]
        if count == 2:
            first, second = self.next_int(size), self.next_int(size - 1)
            low, high = (first, second + 1) if second >= first else (second, first)
            return [agents[low], agents[high]]
        return self._subset(count, agents)

    def _subset(self, count: int, items: Sequence[T]) -> list[T]:
        chosen: list[T] = []
        for i, item in enumerate(items):
            if len(chosen) >= count:
                break
            if self.next_int(len(items) - i) < count - len(chosen):
                chosen.append(item)
        return chosen

    def shuffle(self, items: Sequence[T]) -> list[T]:
        """`shuffle`: java.util.Collections.shuffle, swapping from the end down."""
        result = list(items)
        for i in range(len(result), 1, -1):
            j = self.next_int(i)
            result[i - 1], result[j] = result[j], result[i - 1]
        return result

    def turtle_colour_heading(self) -> tuple[int, int]:
        """The two draws of each new turtle of `create-turtles` and `sprout`: colour, heading."""
        colour = 5 + 10 * self.next_int(BASE_COLOURS)
        return colour, self.next_int(360)

    def ask_order(self, agents: Sequence[T], alive: Sequence[bool] | None = None) -> AskOrder[T]:
        """The order in which `ask` (and `of`) visits `agents`; see AskOrder."""
        return AskOrder(self, agents, alive)


class AskOrder(Iterator[T]):
    """NetLogo's shufflerator: a lazy Fisher-Yates over a copy of the agentset.

    It draws the first agent when made and, each time it hands one out, draws the next before
    the caller runs that agent's commands, so draws made by the commands interleave exactly as
    in NetLogo (none for the last agent). `alive` (turtles that died, by index, read as the
    iteration goes) skips dead agents, drawing again as NetLogo does.
    """

    def __init__(self, rng: MersenneTwister, agents: Sequence[T], alive: Sequence[bool] | None = None) -> None:
        self._rng = rng
        self._copy = list(range(len(agents)))
        self._agents = agents
        self._alive = alive
        self._i = 0
        self._next: int | None = None
        self._fetch()

    def _fetch(self) -> None:
        while True:
            size = len(self._copy)
            if self._i >= size:
                self._next = None
                return
            if self._i < size - 1:
                r = self._i + self._rng.next_int(size - self._i)
                self._next = self._copy[r]
                self._copy[r] = self._copy[self._i]
            else:
                self._next = self._copy[self._i]
            self._i += 1
            if self._alive is None or self._alive[self._next]:
                return

    def __next__(self) -> T:
        if self._next is None:
            raise StopIteration
        current = self._next
        self._fetch()
        return self._agents[current]
