// Animation tracks (frames x named channels at a frame rate) and the file formats vispeech
// writes: vispeech animation JSON, Live Link Face CSV and TalkingHead animation JSON.

/**
 * Animation curves sampled at `fps`: frame k holds the channel values at
 * `startTime + k / fps` seconds of the audio. Frames may be appended while streaming.
 * `phones` is a PhoneSequence dict, `audio` the audio file's name (relative to the
 * animation file), when the file gives them.
 */
export class Animation {
  constructor({ fps, channels, frames = [], startTime = 0, phones = null, audio = null, complete = true }) {
    if (!(fps > 0)) throw new Error(`animation fps must be positive, got ${fps}`);
    this.fps = Number(fps);
    this.channels = channels.map(String);
    this.startTime = Number(startTime) || 0;
    this.phones = phones;
    this.audio = audio;
    this.complete = complete;
    this.frames = [];
    this.append(0, frames);
  }

  /** Number of frames received so far. */
  get length() {
    return this.frames.length;
  }

  /** Seconds (of the audio) at which the frames end: `startTime + length / fps`. */
  get endTime() {
    return this.startTime + this.frames.length / this.fps;
  }

  /** Store `frames` (rows of channel values) from frame `start` on. */
  append(start, frames) {
    for (let k = 0; k < frames.length; k++) {
      const row = frames[k];
      if (!row || row.length !== this.channels.length) {
        throw new Error(`frame ${start + k} has ${row ? row.length : 0} values for ${this.channels.length} channels`);
      }
      const bad = row.findIndex((v) => typeof v !== 'number' || !Number.isFinite(v));
      if (bad >= 0) throw new Error(`frame ${start + k}, value ${bad} is not a number (${JSON.stringify(row[bad])})`);
      this.frames[start + k] = Float32Array.from(row);
    }
  }

  /** Fractional frame position at `t` seconds, clamped to the frames there are. */
  position(t) {
    const last = this.frames.length - 1;
    return Math.min(Math.max((t - this.startTime) * this.fps, 0), Math.max(last, 0));
  }

  /** Channel values at `t` seconds, linearly interpolated between frames, into `out`. */
  sample(t, out = new Float32Array(this.channels.length)) {
    if (!this.frames.length) return out.fill(0);
    const p = this.position(t);
    const i = Math.floor(p);
    const a = this.frames[i] || this.frames[0];
    const b = this.frames[i + 1] || a;
    const w = p - i;
    for (let c = 0; c < out.length; c++) out[c] = a[c] + w * (b[c] - a[c]);
    return out;
  }

  /** The phone (`{symbol, start, end, word, ...}`) sounding at `t` seconds, or null. */
  phoneAt(t) {
    const phones = this.phones && this.phones.phones;
    if (!phones) return null;
    return phones.find((p) => p.start <= t && t < p.end) || null;
  }
}

/** Read an animation file's text: vispeech JSON, TalkingHead JSON or Live Link Face CSV. */
export function parseAnimation(text, name = 'animation') {
  try {
    return parseAnimationText(text, name);
  } catch (err) {  // every error names the file, as vispeech's readers do
    throw err.message.startsWith(`${name}: `) ? err : new Error(`${name}: ${err.message}`);
  }
}

function parseAnimationText(text, name) {
  const trimmed = text.replace(/^\uFEFF/, '').trim();
  if (trimmed.startsWith('{')) {
    let data;
    try {
      data = JSON.parse(trimmed);
    } catch (err) {
      throw new Error(`${name}: not valid JSON (${err.message})`);
    }
    return animationFromJson(data, name);
  }
  if (/^timecode\s*,/i.test(trimmed)) return fromLiveLinkCsv(trimmed, name);
  throw new Error(`${name}: not a vispeech JSON, TalkingHead JSON or Live Link CSV animation`);
}

/** An Animation from a parsed JSON object: vispeech animation JSON or TalkingHead JSON. */
export function animationFromJson(data, name = 'animation') {
  if (data && data.format === 'vispeech-animation') return fromVispeechJson(data, name);
  const anim = data && (data.anim || data);
  if (anim && Array.isArray(anim.dt) && anim.vs && typeof anim.vs === 'object') {
    return fromTalkingHead(anim, name);
  }
  throw new Error(`${name}: JSON is neither a vispeech animation nor a TalkingHead animation`);
}

function fromVispeechJson(data, name) {
  if (data.version !== 1) throw new Error(`${name}: unsupported vispeech animation version ${data.version}`);
  if (!Array.isArray(data.channels) || !Array.isArray(data.frames) || !data.frames.length) {
    throw new Error(`${name}: vispeech animation needs "channels" and a non-empty "frames" array`);
  }
  return new Animation({
    fps: data.fps,
    channels: data.channels,
    frames: data.frames,
    startTime: data.start_time || 0,
    phones: data.phones || null,
    audio: typeof data.audio === 'string' ? data.audio : null,
  });
}

// TalkingHead blend-shape animation, as vispeech writes and reads it: frame i starts after
// sum(dt[0..i-1]) ms and lasts dt[i] ms. `null` keeps the previous value, `[min, max]` (random
// in TalkingHead) counts as its middle. Unequal durations are resampled at the median rate.
function fromTalkingHead(anim, name) {
  const dt = anim.dt.map(Number);
  if (!dt.length || dt.some((d) => !(d > 0))) throw new Error(`${name}: TalkingHead "dt" must hold positive durations (ms)`);
  const channels = Object.keys(anim.vs);
  const starts = [0];
  for (let i = 1; i < dt.length; i++) starts.push(starts[i - 1] + dt[i - 1] / 1000);
  const curves = channels.map((ch) => {
    const values = anim.vs[ch];
    if (!Array.isArray(values) || values.length !== dt.length) {
      throw new Error(`${name}: TalkingHead "vs.${ch}" must hold one value per "dt" entry`);
    }
    let last = 0;
    return values.map((v) => {
      if (Array.isArray(v)) last = (Number(v[0]) + Number(v[v.length - 1])) / 2;
      else if (v !== null && v !== undefined) last = Number(v);
      return last;
    });
  });
  const sorted = [...dt].sort((a, b) => a - b);
  const fps = roundRate(1000 / sorted[Math.floor(sorted.length / 2)]);
  const n = Math.max(1, Math.round((starts[starts.length - 1] + dt[dt.length - 1] / 1000) * fps));
  return new Animation({ fps, channels, frames: resample(starts, curves, fps, n) });
}

const LIVE_LINK_META = new Set(['timecode', 'blendshapecount']);
const TIMECODE = /^\s*(\d+):(\d{1,2}):(\d{1,2})[:;](\d+)(?:\.(\d+))?\s*$/;
const TIMECODE_RATES = [24, 25, 30, 48, 50, 60, 72, 90, 100, 120, 240];
const NOMINAL_FPS = [...TIMECODE_RATES, 24000 / 1001, 30000 / 1001, 60000 / 1001];

/**
 * Read a Live Link Face CSV (`Timecode,BlendshapeCount,EyeBlinkLeft,...`) as vispeech does.
 * The timecode `HH:MM:SS:FF.fff` counts frames at the rate where FF wraps to the next
 * second (60, the app's, when the take never wraps). Timecodes under an hour are utterance
 * time (vispeech writes from 00:00:00:00); later ones are the app's time of day and count
 * from the first row.
 */
export function fromLiveLinkCsv(text, name = 'animation') {
  const lines = text.split(/\r?\n/).filter((line) => line.trim());
  const header = lines[0].split(',').map((s) => s.trim());
  const keep = header.map((h, i) => (LIVE_LINK_META.has(h.toLowerCase()) ? -1 : i)).filter((i) => i >= 0);
  const tcColumn = header.findIndex((h) => h.toLowerCase() === 'timecode');
  const codes = [];
  const rows = [];
  for (let r = 1; r < lines.length; r++) {
    const cells = lines[r].split(',');
    if (cells.length !== header.length) throw new Error(`${name}: line ${r + 1} has ${cells.length} fields, the header has ${header.length}`);
    const code = TIMECODE.exec(cells[tcColumn]);
    if (!code) throw new Error(`${name}: line ${r + 1}: bad timecode ${JSON.stringify(cells[tcColumn])} (want HH:MM:SS:FF.fff)`);
    codes.push(code);
    const row = keep.map((i) => (cells[i].trim() === '' ? NaN : Number(cells[i])));
    if (row.some((v) => !Number.isFinite(v))) throw new Error(`${name}: line ${r + 1}: a value is not a number`);
    rows.push(row);
  }
  if (!rows.length) throw new Error(`${name}: Live Link CSV has no rows`);
  const rate = timecodeRate(codes);
  const times = codes.map((c) => Number(c[1]) * 3600 + Number(c[2]) * 60 + Number(c[3])
    + (Number(c[4]) + (c[5] ? Number(`0.${c[5]}`) : 0)) / rate);
  for (let i = 1; i < times.length; i++) {
    if (!(times[i] > times[i - 1])) throw new Error(`${name}: line ${i + 2}: timecode does not increase`);
  }
  const span = times[times.length - 1] - times[0];
  const fps = times.length > 1 ? nominalRate((times.length - 1) / span, rate) : rate;
  const channels = keep.map((i) => header[i]);
  const curves = channels.map((_, c) => rows.map((row) => row[c]));
  const rel = times.map((t) => t - times[0]);
  return new Animation({
    fps,
    channels,
    frames: resample(rel, curves, fps, Math.round(span * fps) + 1),
    startTime: times[0] < 3600 ? times[0] : 0,
  });
}

// The timecode's frames per second, as vispeech's reader takes it: where FF wraps, the highest
// frame + 1, or the nominal rate just above it when the frame numbers never shown at a second's
// end are fewer than the rows' usual step (every 5th frame of 60 fps ends at 55); a take that
// never wraps: 60, or the nominal rate above its highest frame.
function timecodeRate(codes) {
  const frames = codes.map((c) => Number(c[4]));
  const seconds = codes.map((c) => `${c[1]}:${c[2]}:${c[3]}`);
  const needed = Math.max(...frames) + 1;
  if (new Set(seconds).size === 1) return TIMECODE_RATES.find((r) => r >= Math.max(needed, 60)) || needed;
  const steps = [];
  for (let i = 1; i < frames.length; i++) {
    if (seconds[i] === seconds[i - 1] && frames[i] > frames[i - 1]) steps.push(frames[i] - frames[i - 1]);
  }
  steps.sort((a, b) => a - b);
  const mid = steps.length >> 1;
  const step = !steps.length ? 1 : steps.length % 2 ? steps[mid] : (steps[mid - 1] + steps[mid]) / 2;
  return TIMECODE_RATES.find((r) => needed <= r && r < needed + step) || needed;
}

function nominalRate(measured, rate) {
  const nearest = [...NOMINAL_FPS, rate, Math.round(measured)].reduce((a, b) => (Math.abs(b - measured) < Math.abs(a - measured) ? b : a));
  return Math.abs(nearest - measured) <= 1e-4 * measured ? nearest : measured;
}

// A frame rate measured from rounded times, snapped to a whole number when that close.
function roundRate(fps) {
  return Math.abs(fps - Math.round(fps)) < 1e-3 ? Math.round(fps) : fps;
}

// Linear resampling of key curves (values at increasing `times`, seconds) onto `n` frames
// at `fps`, holding the last key.
function resample(times, curves, fps, n) {
  const frames = [];
  let j = 0;
  for (let k = 0; k < n; k++) {
    const t = k / fps;
    while (j < times.length - 2 && times[j + 1] <= t) j++;
    const span = times[j + 1] - times[j];
    const w = span > 0 ? Math.min(Math.max((t - times[j]) / span, 0), 1) : 0;
    frames.push(curves.map((v) => (v.length > 1 ? v[j] + w * (v[j + 1] - v[j]) : v[0])));
  }
  return frames;
}
