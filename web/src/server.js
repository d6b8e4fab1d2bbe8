// Calls to the vispeech server (see docs/web.md for the contract). URLs are relative to the
// page, so the app also works when the server is mounted under a path prefix.
import { openMicrophone } from './microphone.js';
import { decodePcm16 } from './performer.js';

const LIVE_MARGIN = 0.1; // seconds a live frame may take beyond the stream's delay before it is late

const DEFAULT_CONFIG = {
  avatar_url: null, languages: ['sv', 'en'], language_names: {}, chat_languages: ['sv', 'en'], models: [],
  default_model: null, fps: 30,
};

async function postJson(path, body) {
  const response = await fetch(path, {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify(body),
  });
  const data = await response.json().catch(() => ({}));
  if (!response.ok) {
    const err = new Error(data.detail || data.message || `${path}: HTTP ${response.status}`);
    err.status = response.status;
    throw err;
  }
  return data;
}

/** GET api/config; the defaults (2D face, sv/en) when no server answers. */
export async function fetchConfig() {
  try {
    const response = await fetch('api/config');
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    return { ...DEFAULT_CONFIG, ...(await response.json()) };
  } catch {
    return { ...DEFAULT_CONFIG, offline: true };
  }
}

/**
 * POST api/speak: `{audio_url, animation, text, cached}` for `text`, the animation with the
 * channels of the non-verbal layers `life` (blink, gaze, head, brows, breath, expression) drawn with `seed`.
 */
export function requestSpeech({ text, language, model = null, rate = 1.0, life = [], seed = 0 }) {
  return postJson('api/speak', { text, language, model, rate, life, seed });
}

/**
 * POST api/chat: `{reply, language, session, speech}`; `session` (null: a new one) carries the
 * conversation on; `speak: false` asks for the reply text only.
 */
export function requestChat({ message, language, session = null, speak = true, life = [], seed = 0 }) {
  return postJson('api/chat', { message, language, session, speak, life, seed });
}

/** Whether `err` says the chat session is gone (the server restarted or dropped it). */
export const sessionGone = (err) => /unknown or expired chat session/.test(err.message);

/**
 * Speak `text` through the api/stream WebSocket, feeding frames and audio chunks to
 * `performer` as they arrive. Resolves when the server sends `end`.
 */
export function streamSpeech(performer, { text, language, model = null }) {
  return streamMessage(performer, { type: 'text', text, language, model });
}

/**
 * Send a chat message through the api/stream WebSocket: the reply is spoken clause by clause as
 * the chat bot writes it; `onreply({text, language, session, start})` hears each clause as its
 * audio begins to arrive. Resolves when the server sends `end`.
 */
export function streamChat(performer, { message, language, session = null, model = null }, onreply) {
  return streamMessage(performer, { type: 'chat', message, language, session, model }, onreply);
}

function streamMessage(performer, first, onreply = () => {}) {
  const url = socketUrl('api/stream');
  return new Promise((resolve, reject) => {
    const socket = new WebSocket(url);
    let sampleRate = 22050;
    let started = false;
    let done = false;
    const finish = (err) => {
      if (done) return;
      done = true;
      socket.close();
      if (err && started) performer.endStream(); // what came is played to its end
      if (err) reject(err);
      else resolve();
    };
    socket.onopen = () => socket.send(JSON.stringify(first));
    socket.onerror = () => finish(new Error('stream connection failed'));
    socket.onclose = () => finish(new Error('stream closed before its end'));
    socket.onmessage = (event) => {
      let msg;
      try {
        msg = JSON.parse(event.data);
        if (msg.type === 'start') {
          sampleRate = msg.sample_rate || sampleRate;
          performer.beginStream({ fps: msg.fps, channels: msg.channels });
          started = true;
        } else if (msg.type === 'audio') {
          performer.streamAudio(msg.start, decodePcm16(msg.pcm16), sampleRate);
        } else if (msg.type === 'frames') {
          performer.streamFrames(msg.start_frame, msg.frames);
        } else if (msg.type === 'reply') {
          onreply(msg);
        } else if (msg.type === 'end') {
          started = false;
          performer.endStream();
          finish();
        } else if (msg.type === 'error') {
          finish(new Error(msg.message || 'stream error'));
        }
      } catch (err) {
        finish(err);
      }
    };
  });
}

/**
 * Animate the microphone live through the api/listen WebSocket: 20 ms chunks of 16-bit PCM go
 * to the server as they are captured and the frames coming back drive `performer`. Resolves,
 * once the server has opened the stream, to a handle: `stop()` ends the audio and resolves when
 * the server has sent the last frames; `done` settles when the stream ends (rejects on an error or
 * a lost connection). `onwarning(message)` hears the server's warnings (frames late).
 */
export async function listenLive(performer, { model = null, onwarning = () => {} } = {}) {
  const microphone = await openMicrophone(performer.context);
  const socket = new WebSocket(socketUrl('api/listen'));
  socket.binaryType = 'arraybuffer';
  let settle;
  const done = new Promise((resolve, reject) => {
    settle = (err) => (err ? reject(err) : resolve());
  });
  let finished = false;
  const finish = (err) => {
    if (finished) return;
    finished = true;
    microphone.stop();
    socket.close();
    settle(err);
  };
  const handle = {
    done,
    stop() {
      microphone.stop();
      if (socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify({ type: 'stop' }));
      else finish();
      return done;
    },
  };
  return new Promise((resolve, reject) => {
    done.catch(reject); // an error before the stream opened
    socket.onopen = () => socket.send(JSON.stringify({
      type: 'start', sample_rate: microphone.sampleRate, encoding: 'pcm16', model,
    }));
    socket.onerror = () => finish(new Error('listen connection failed'));
    socket.onclose = () => finish(new Error('listen stream closed before its end'));
    socket.onmessage = (event) => {
      try {
        const msg = JSON.parse(event.data);
        if (msg.type === 'start') {
          performer.beginLive({ fps: msg.fps, channels: msg.channels, lag: msg.delay + LIVE_MARGIN });
          microphone.start((pcm, time) => {
            performer.liveOrigin(time);
            if (socket.readyState === WebSocket.OPEN) socket.send(pcm);
          });
          resolve(handle);
        } else if (msg.type === 'frames') {
          performer.streamFrames(msg.start_frame, msg.frames);
        } else if (msg.type === 'warning') {
          onwarning(msg.message);
        } else if (msg.type === 'end') {
          performer.endStream();
          finish();
        } else if (msg.type === 'error') {
          finish(new Error(msg.message || 'listen error'));
        }
      } catch (err) {
        finish(err);
      }
    };
  });
}

/** The WebSocket URL of `path`, relative to the page. */
function socketUrl(path) {
  const url = new URL(path, window.location.href);
  url.protocol = url.protocol === 'https:' ? 'wss:' : 'ws:';
  return url;
}
