// Calls to the vispeech server (see docs/web.md for the contract). URLs are relative to the
// page, so the app also works when the server is mounted under a path prefix.
import { decodePcm16 } from './performer.js';

const DEFAULT_CONFIG = { avatar_url: null, languages: ['sv', 'en'], models: [], default_model: null, fps: 30 };

async function postJson(path, body) {
  const response = await fetch(path, {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify(body),
  });
  const data = await response.json().catch(() => ({}));
  if (!response.ok) throw new Error(data.detail || data.message || `${path}: HTTP ${response.status}`);
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

/** POST api/speak: `{audio_url, animation, text, cached}` for `text`. */
export function requestSpeech({ text, lang, model = null, rate = 1.0 }) {
  return postJson('api/speak', { text, lang, model, rate });
}

/** POST api/chat: `{reply, lang, speech}`; `speak: false` asks for the reply text only. */
export function requestChat({ message, lang, speak = true }) {
  return postJson('api/chat', { message, lang, speak });
}

/**
 * Speak `text` through the api/stream WebSocket, feeding frames and audio chunks to
 * `performer` as they arrive. Resolves when the server sends `end`.
 */
export function streamSpeech(performer, { text, lang, model = null }) {
  const url = new URL('api/stream', window.location.href);
  url.protocol = url.protocol === 'https:' ? 'wss:' : 'ws:';
  return new Promise((resolve, reject) => {
    const socket = new WebSocket(url);
    let sampleRate = 22050;
    let done = false;
    const finish = (err) => {
      if (done) return;
      done = true;
      socket.close();
      if (err) reject(err);
      else resolve();
    };
    socket.onopen = () => socket.send(JSON.stringify({ type: 'text', text, lang, model }));
    socket.onerror = () => finish(new Error('stream connection failed'));
    socket.onclose = () => finish(new Error('stream closed before its end'));
    socket.onmessage = (event) => {
      let msg;
      try {
        msg = JSON.parse(event.data);
        if (msg.type === 'start') {
          sampleRate = msg.sample_rate || sampleRate;
          performer.beginStream({ fps: msg.fps, channels: msg.channels });
        } else if (msg.type === 'audio') {
          performer.streamAudio(msg.start, decodePcm16(msg.pcm16), sampleRate);
        } else if (msg.type === 'frames') {
          performer.streamFrames(msg.start_frame, msg.frames);
        } else if (msg.type === 'end') {
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
