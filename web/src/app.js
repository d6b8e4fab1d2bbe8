// What every page shares: the avatar on its stage, the performer, the draw loop and the
// `window.vispeech` handle that tests and embedding pages use.
import { Animation, animationFromJson, parseAnimation } from './animation.js';
import { createAvatar } from './avatar.js';
import { Performer } from './performer.js';
import { fetchConfig, listenLive, requestSpeech } from './server.js';

const FACE2D_SRC = 'static/face2d.js';
const LIFE = ['blink', 'gaze', 'head', 'brows', 'breath', 'expression']; // the non-verbal layers the pages ask the server for

/** An Animation from an Animation, a parsed JSON object, or a file's text. */
export function toAnimation(data, name = 'animation') {
  if (data instanceof Animation) return data;
  if (typeof data === 'string') return parseAnimation(data, name);
  return animationFromJson(data, name);
}

/**
 * The audio URL to play with an animation loaded from `animUrl`: `audioUrl` when given, else
 * the file the animation names (vispeech JSON's `audio`), beside the animation file.
 */
export function audioFor(animation, animUrl, audioUrl) {
  if (audioUrl) return audioUrl;
  return animation.audio ? new URL(animation.audio, new URL(animUrl, window.location.href)).href : null;
}

/** Fetch `url` and check the answer; `kind` is 'text' or 'arrayBuffer'. */
export async function fetchBody(url, kind) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(`${url}: HTTP ${response.status}`);
  return response[kind]();
}

async function loadAvatar(stage, url, report) {
  try {
    return await createAvatar(stage, url, FACE2D_SRC);
  } catch (err) {
    if (!url) throw err;
    report(`Could not load the 3D head (${err.message}); showing the 2D face.`);
    return createAvatar(stage, null, FACE2D_SRC);
  }
}

function addOverlay(stage, performer) {
  const button = document.createElement('button');
  button.className = 'unlock';
  button.type = 'button';
  button.textContent = '▶ Click to play with sound';
  button.hidden = true;
  button.onclick = () => performer.unlock();
  stage.appendChild(button);
  return button;
}

/**
 * Start the avatar on `stage`, run the page's `setup(app)`, then mark `window.vispeech`
 * ready.
 *
 * Page URL options: `avatar=URL` (a GLB or VRM; empty for the 2D face) overrides the server's
 * avatar, `idle=0` turns idle blinks and head sway off, and the non-verbal layers the page
 * asks the server for with each utterance.
 */
export async function startApp({ stage, setup = async () => {}, onstate = () => {}, report = console.warn }) {
  const params = new URLSearchParams(window.location.search);
  const config = await fetchConfig();
  const avatarUrl = params.has('avatar') ? params.get('avatar') || null : config.avatar_url;
  const avatar = await loadAvatar(stage, avatarUrl, report);
  const credit = (avatarUrl === config.avatar_url && config.avatar_credit) || avatar.credit;
  if (avatarUrl && credit) {
    const note = document.createElement('div');
    note.className = 'credit';
    note.textContent = credit;
    stage.appendChild(note);
  }

  let overlay = null;
  const lively = params.get('idle') !== '0';
  let utterances = 0;
  const performer = new Performer(avatar, {
    idle: lively,
    onstate: (state) => {
      if (overlay) overlay.hidden = state !== 'waiting';
      onstate(state);
    },
  });
  overlay = addOverlay(stage, performer);
  const unlock = () => performer.unlock().catch(() => {});
  window.addEventListener('pointerdown', unlock);
  window.addEventListener('keydown', unlock);

  const draw = () => {
    performer.tick();
    requestAnimationFrame(draw);
  };
  requestAnimationFrame(draw);

  const app = {
    ready: false,
    config,
    avatar,
    performer,
    /** The non-verbal layers the page asks the server for (none with `idle=0`). */
    life: lively ? LIFE : [],
    /** `{life, seed}` for the next utterance's request: the page's layers, a new seed each time. */
    lifeOptions: () => ({ life: app.life, seed: utterances++ }),
    /** Utterance time (seconds) of the pose on screen. */
    clock: () => performer.shownTime,
    /** Animation frame on screen (-1 when none). */
    frameIndex: () => performer.shownFrame,
    /** Utterance time (seconds) of the audio clock now. */
    audioTime: () => performer.time(),
    /** Current morph influence of ARKit channel `name` on the head. */
    influences: (name) => avatar.influence(name),
    /** Current weight of a VRM head's expression `name` (`aa`, `ih`, ..., `blinkLeft`); null for other heads. */
    expression: (name) => avatar.expression(name),
    /** Load `animation` (object, text or Animation) with optional audio at `audioUrl` and play it. */
    async playAnimation(animation, audioUrl = null, { autoplay = true } = {}) {
      const anim = toAnimation(animation);
      const audio = audioUrl ? await performer.decodeAudio(await fetchBody(audioUrl, 'arrayBuffer')) : null;
      performer.load(anim, audio);
      if (autoplay) performer.play(0);
      return anim;
    },
    /** Play a `/api/speak`-shaped answer: `{audio_url, animation}`. */
    playSpeech(speech) {
      return app.playAnimation(speech.animation, speech.audio_url);
    },
    /** Ask the server to speak `text` in `language`, play it, and return its answer. */
    async speak(text, language = 'en', model = config.default_model) {
      const speech = await requestSpeech({ text, language, model, ...app.lifeOptions() });
      await app.playSpeech(speech);
      return speech;
    },
    /**
     * Animate the microphone live (the server's audio model unless `model` names one); resolves to
     * a handle with `stop()` and `done` once the stream is open (see server.js `listenLive`).
     */
    listen: (model = null, onwarning = undefined) => listenLive(performer, { model, onwarning }),
    /** Stop the sound and hold the pose at `t` seconds. */
    seek: (t) => performer.seek(t),
    play: (from = null) => performer.play(from),
    pause: () => performer.pause(),
  };
  window.vispeech = app;
  performer.tick();
  try {
    await setup(app);
  } finally {
    app.ready = true;
  }
  return app;
}
