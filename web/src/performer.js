// Plays audio and animation on one clock: the AudioContext's. The frame shown is the track
// interpolated at `audioContext.currentTime - outputLatency - t0`, where t0 is the context
// time at which utterance time 0 sounds.
import { MORPH_INDEX, MORPH_NAMES, morphName } from './arkit.js';
import { Animation } from './animation.js';
import { IdleMotion } from './idle.js';

const LEAD = 0.08; // seconds between scheduling and the first sample sounding
const STREAM_BUFFER = 0.25; // seconds of streamed audio buffered before playback starts
const FADE = 0.2; // seconds to ease into and out of an animation's first and last frame
const LIVE_SLACK = 0.02; // seconds added when a live frame came late, beyond its lateness
const LAYER_BLEND = 0.4; // seconds to hand the head and the blinks from idle motion to an utterance's layers and back
const BREATH_LIFT = 0.01; // radians the head tilts up with full lungs (the `breath` channel at 1)
export const HEAD_CHANNELS = ['headpitch', 'headyaw', 'headroll']; // lower-cased, in setHeadRotation's order
const RADIANS_PER_DEGREE = Math.PI / 180; // tracks carry head rotation in degrees (vispeech.Utterance)

/**
 * The head [pitch, yaw, roll] (radians) a track's frame `values` asks for: the head channels at
 * indices `head` (degrees; -1 or a null `head`: 0), tilted up by the breath at index `breath` (-1: none).
 */
export function trackHeadPose(values, head, breath) {
  const pose = head ? head.map((c) => (c >= 0 ? values[c] * RADIANS_PER_DEGREE : 0)) : [0, 0, 0];
  if (breath >= 0) pose[0] -= BREATH_LIFT * values[breath];
  return pose;
}

/** Decode base64 little-endian 16-bit PCM into floats in [-1, 1). */
export function decodePcm16(base64) {
  const bytes = Uint8Array.from(atob(base64), (c) => c.charCodeAt(0));
  const view = new DataView(bytes.buffer);
  const out = new Float32Array(bytes.length >> 1);
  for (let i = 0; i < out.length; i++) out[i] = view.getInt16(2 * i, true) / 32768;
  return out;
}

/** Smooth step from 0 to 1 as `x` goes from 0 to 1. */
const ease = (x) => x * x * (3 - 2 * x);

/**
 * Drives an avatar from an Animation and its audio. States: `idle` (nothing loaded or
 * finished: blinks and head sway only), `buffering` (a stream began, its clock has not),
 * `playing`, `paused` (frozen at a time, idle motion included) and `waiting` (the browser
 * holds audio back until a user gesture).
 *
 * An animation that carries non-verbal layers (vispeech.motion.life: any of them not all 0)
 * drives the face in their place while it is loaded: `headPitch`/`headYaw`/`headRoll` (degrees)
 * the head instead of the idle sway, `eyeBlinkLeft`/`Right` the blinks instead of the idle ones
 * (the 2D face keeps its own), and `breath` (0..1) tilts the head up a little. The head and the
 * blinks pass from idle motion to the layers and back over LAYER_BLEND seconds, never in a jump.
 */
export class Performer {
  constructor(avatar, { idle = true, onstate = () => {} } = {}) {
    this.avatar = avatar;
    this.context = new AudioContext();
    this.idle = idle ? new IdleMotion() : null;
    this.onstate = onstate;
    this.animation = null;
    this.channelIndex = [];
    this.segments = []; // audio: [{start (seconds), buffer}]
    this.sources = [];
    this.t0 = null;
    this.pausedAt = null;
    this.live = null; // live audio: {lag} (seconds from capturing audio to showing its frame)
    this.idleClock = 0;
    this.lastTick = null;
    this.weights = new Float32Array(MORPH_NAMES.length);
    this.values = null;
    this.shownTime = 0;
    this.shownFrame = -1;
    this.layers = { head: null, breath: -1, blinks: false }; // the loaded animation's layer channels
    this.blend = { head: 0, blinks: 0 }; // 0: idle motion drives them, 1: the layers do
    this.headOffset = [0, 0, 0]; // [pitch, yaw, roll] the layers last added to idle motion's head
    this.headMoved = false;
    this.state = 'idle';
    this.context.onstatechange = () => this.updateState();
  }

  /** Seconds of utterance time now: the clock both audio and animation follow. */
  time() {
    if (this.pausedAt !== null) return this.pausedAt;
    if (this.t0 === null) return 0;
    return this.context.currentTime - (this.context.outputLatency || 0) - this.t0;
  }

  /** Seconds covered by the animation and the audio, whichever ends later. */
  get duration() {
    const audioEnd = Math.max(0, ...this.segments.map((s) => s.start + s.buffer.duration));
    return Math.max(audioEnd, this.animation ? this.animation.endTime : 0);
  }

  /** Let audio play; call from a user gesture (click, key press). */
  unlock() {
    return this.context.state === 'running' ? Promise.resolve() : this.context.resume();
  }

  /** Decode a complete audio file (WAV, MP3, ...) into an AudioBuffer. */
  decodeAudio(arrayBuffer) {
    return this.context.decodeAudioData(arrayBuffer);
  }

  /** Replace what is loaded by `animation` and optional `audioBuffer`, paused at 0. */
  load(animation, audioBuffer = null) {
    this.stopSources();
    this.live = null;
    this.setAnimation(animation);
    this.segments = audioBuffer ? [{ start: 0, buffer: audioBuffer }] : [];
    this.t0 = null;
    this.pausedAt = 0;
    this.tick();
  }

  /** Play from `from` seconds (default: where paused, or the start). */
  play(from = null) {
    if (!this.animation && !this.segments.length) return;
    let t = from ?? this.pausedAt ?? 0;
    if (t >= this.duration) t = 0;
    this.stopSources();
    this.pausedAt = null;
    this.t0 = this.context.currentTime + LEAD - t;
    for (const { start, buffer } of this.segments) this.schedule(start, buffer, t);
    this.unlock().catch(() => {});
    this.updateState();
  }

  /** Pause where the clock is now. */
  pause() {
    if (this.state !== 'playing' && this.state !== 'waiting') return;
    this.seek(this.time());
  }

  /** Stop the sound and hold the pose at `t` seconds. */
  seek(t) {
    this.stopSources();
    this.pausedAt = Math.min(Math.max(Number(t) || 0, 0), this.duration);
    this.t0 = null;
    this.tick();
    this.updateState();
  }

  // --- streaming: frames and audio chunks arrive while the utterance plays ---

  /** Start a streamed utterance of `channels` at `fps`. */
  beginStream({ fps, channels }) {
    this.stopSources();
    this.setAnimation(new Animation({ fps, channels, complete: false }));
    this.segments = [];
    this.t0 = null;
    this.pausedAt = null;
    this.live = null;
    this.updateState();
  }

  /**
   * Start animating live audio (the microphone's; nothing is played): frames of `channels` at
   * `fps` arrive as the server computes them, each shown `lag` seconds after its audio was
   * captured. The clock starts with `liveOrigin`; a frame that arrives after its time pushes it back.
   */
  beginLive({ fps, channels, lag }) {
    this.beginStream({ fps, channels });
    this.live = { lag };
  }

  /** The context time (s) at which the live audio's first sample was captured. */
  liveOrigin(contextTime) {
    if (!this.live || this.t0 !== null) return;
    this.t0 = contextTime + this.live.lag;
    this.updateState();
  }

  /** Add streamed frames from frame `startFrame` on. */
  streamFrames(startFrame, frames) {
    this.animation.append(startFrame, frames);
    if (this.live) {
      const late = this.t0 === null ? 0 : this.time() - (this.animation.endTime - 1 / this.animation.fps);
      if (late > 0) this.t0 += late + LIVE_SLACK;
      return;
    }
    this.startStreamClock();
  }

  /** Add a chunk of mono `samples` at `sampleRate` Hz that starts `start` seconds in. */
  streamAudio(start, samples, sampleRate) {
    const buffer = this.context.createBuffer(1, samples.length, sampleRate);
    buffer.copyToChannel(samples, 0);
    this.segments.push({ start, buffer });
    this.startStreamClock();
    if (this.t0 === null) return; // paused: played when resumed
    const late = this.t0 + start - (this.context.currentTime + 0.01);
    if (late < 0) this.t0 -= late - LEAD; // chunk arrived late: wait for it, animation too
    this.schedule(start, buffer, 0);
  }

  /** The server sent everything. */
  endStream() {
    this.animation.complete = true;
  }

  startStreamClock() {
    if (this.t0 === null && this.pausedAt === null) {
      this.t0 = this.context.currentTime + STREAM_BUFFER;
      this.unlock().catch(() => {});
      this.updateState();
    }
  }

  // --- internals ---

  setAnimation(animation) {
    this.animation = animation;
    this.channelIndex = animation.channels.map((c) => {
      const name = morphName(c);
      return name === null ? -1 : MORPH_INDEX.get(name);
    });
    this.values = new Float32Array(animation.channels.length);
    const moving = (c) => c >= 0 && animation.frames.some((row) => row && row[c] !== 0);
    const find = (name) => animation.channels.findIndex((c) => c.toLowerCase() === name);
    const head = HEAD_CHANNELS.map(find);
    const breath = find('breath');
    const blinks = ['eyeBlinkLeft', 'eyeBlinkRight'].map((name) => this.channelIndex.indexOf(MORPH_INDEX.get(name)));
    this.layers = {
      head: head.some(moving) ? head : null,
      breath: moving(breath) ? breath : -1,
      blinks: blinks.some(moving),
    };
  }

  /**
   * The head [pitch, yaw, roll] (radians): idle motion's `idleHead` (null when it is off), moved
   * towards the layers' pose while they drive the head (their last offset is held while blending out).
   */
  headPose(idleHead, showing) {
    const base = idleHead || [0, 0, 0];
    const { head, breath } = this.layers;
    if (showing && (head || breath >= 0)) {
      // head channels replace the idle sway; the breath's lift adds to whichever drives the head
      this.headOffset = trackHeadPose(this.values, head, breath).map((v, i) => v - (head ? base[i] : 0));
    }
    const blend = ease(this.blend.head);
    return base.map((v, i) => v + blend * this.headOffset[i]);
  }

  schedule(start, buffer, from) {
    const offset = Math.max(0, from - start);
    if (offset >= buffer.duration) return;
    const source = this.context.createBufferSource();
    source.buffer = buffer;
    source.connect(this.context.destination);
    source.start(Math.max(this.context.currentTime, this.t0 + start + offset), offset);
    source.onended = () => {
      this.sources = this.sources.filter((s) => s !== source);
    };
    this.sources.push(source);
  }

  stopSources() {
    for (const source of this.sources) {
      source.onended = null;
      try {
        source.stop();
      } catch {
        // never started
      }
    }
    this.sources = [];
  }

  updateState() {
    let state;
    if (this.pausedAt !== null) state = 'paused';
    else if (this.t0 === null) state = this.animation && !this.animation.complete ? 'buffering' : 'idle';
    else state = this.context.state === 'running' ? 'playing' : 'waiting';
    if (state !== this.state) {
      this.state = state;
      this.onstate(state);
    }
  }

  /** Pose the avatar for the clock's time and draw it; call once per display frame. */
  tick(now = performance.now() / 1000) {
    const elapsed = this.lastTick === null ? 0 : Math.min(now - this.lastTick, 0.1);
    this.lastTick = now;
    if (this.pausedAt === null) this.idleClock += elapsed;

    if (this.t0 !== null && this.pausedAt === null && this.animation && this.animation.complete
        && this.time() > this.duration + FADE) {
      this.t0 = null; // finished: back to idle, animation kept for replay
      this.updateState();
    }
    const t = this.time();
    const weights = this.weights.fill(0);
    const anim = this.animation;
    const running = this.t0 !== null || this.pausedAt !== null;
    const showing = Boolean(anim && anim.length && running); // a frame of the animation is on screen
    this.shownTime = t;
    this.shownFrame = -1;
    if (showing) {
      const fadeIn = 1 - (anim.startTime - t) / FADE;
      const fadeOut = anim.complete ? 1 - (t - anim.endTime) / FADE : 1;
      const fade = Math.min(1, Math.max(0, Math.min(fadeIn, fadeOut)));
      anim.sample(t, this.values);
      for (let c = 0; c < this.values.length; c++) {
        const k = this.channelIndex[c];
        if (k >= 0) weights[k] = Math.min(1, Math.max(0, this.values[c] * fade));
      }
      this.shownFrame = Math.round(anim.position(t));
    }

    const step = elapsed / LAYER_BLEND;
    const toward = (blend, on) => Math.min(1, Math.max(0, blend + (on ? step : -step)));
    this.blend.head = toward(this.blend.head, showing && (this.layers.head || this.layers.breath >= 0));
    this.blend.blinks = toward(this.blend.blinks, showing && this.layers.blinks);
    if (this.idle && !this.avatar.blinks) {
      const blink = this.idle.blink(this.idleClock) * (1 - ease(this.blend.blinks));
      for (const name of ['eyeBlinkLeft', 'eyeBlinkRight']) {
        const k = MORPH_INDEX.get(name);
        weights[k] = Math.max(weights[k], blink);
      }
    }
    if (this.idle || this.blend.head > 0 || this.headMoved) {
      this.avatar.setHeadRotation(...this.headPose(this.idle && this.idle.head(this.idleClock), showing));
      this.headMoved = this.blend.head > 0;
    }
    this.avatar.setWeights(weights);
    this.avatar.render(this.idleClock);
  }
}
