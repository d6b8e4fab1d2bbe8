// Idle motion: blinks at random 2-6 s intervals and a slow, small head sway, so that a face
// waiting between utterances is never frozen.

/** A small seeded random generator (mulberry32) returning numbers in [0, 1). */
export function seededRandom(seed) {
  let a = seed >>> 0;
  return () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

const CLOSE = 0.07; // seconds for the lids to close
const HOLD = 0.03;
const OPEN = 0.13;

/** Smooth 1-D value noise in [-1, 1]: random knots every `period` seconds, eased between. */
class SmoothNoise {
  constructor(random, period) {
    this.random = random;
    this.period = period;
    this.knots = [];
  }

  at(t) {
    const x = Math.max(t, 0) / this.period;
    const i = Math.floor(x);
    while (this.knots.length < i + 2) this.knots.push(2 * this.random() - 1);
    const w = x - i;
    const s = w * w * (3 - 2 * w);
    return this.knots[i] + s * (this.knots[i + 1] - this.knots[i]);
  }
}

/** Blinks and head sway as functions of an idle clock (seconds, never running backwards). */
export class IdleMotion {
  constructor(seed = 1) {
    this.random = seededRandom(seed);
    this.blinkStart = 1 + 2 * this.random();
    this.sway = [0, 1, 2].map(() => [new SmoothNoise(this.random, 2.6), new SmoothNoise(this.random, 0.9)]);
  }

  /** How closed the eyes are (0..1) at `t` seconds. */
  blink(t) {
    while (t > this.blinkStart + CLOSE + HOLD + OPEN) this.blinkStart += 2 + 4 * this.random();
    const dt = t - this.blinkStart;
    if (dt < 0) return 0;
    if (dt < CLOSE) return dt / CLOSE;
    if (dt < CLOSE + HOLD) return 1;
    return 1 - (dt - CLOSE - HOLD) / OPEN;
  }

  /** Head [pitch, yaw, roll] in radians (within about 2 degrees) at `t` seconds. */
  head(t) {
    const amplitude = [0.022, 0.035, 0.014];
    return this.sway.map(([slow, quick], axis) => amplitude[axis] * (0.8 * slow.at(t) + 0.2 * quick.at(t)));
  }
}
