// Microphone capture for live audio (api/listen): getUserMedia into an AudioWorklet that cuts
// the input into chunks of 16-bit little-endian PCM at the AudioContext's sample rate.

const PROCESSOR = 'vispeech-pcm-chunks';
const loaded = new WeakMap(); // AudioContext -> the promise of its worklet module

// Runs on the audio thread: mono input in, a chunk of `size` 16-bit samples out every time one
// is full, with the context time (seconds) of its first sample.
const WORKLET = `
class PcmChunks extends AudioWorkletProcessor {
  constructor(options) {
    super();
    this.size = options.processorOptions.size;
    this.chunk = new Int16Array(this.size);
    this.filled = 0;
    this.time = 0;
  }
  process(inputs) {
    const input = inputs[0] && inputs[0][0];
    if (!input) return true;
    for (let i = 0; i < input.length; i++) {
      if (this.filled === 0) this.time = currentTime + i / sampleRate;
      this.chunk[this.filled++] = Math.max(-32768, Math.min(32767, Math.round(input[i] * 32768)));
      if (this.filled === this.size) {
        this.port.postMessage({ pcm: this.chunk.buffer, time: this.time }, [this.chunk.buffer]);
        this.chunk = new Int16Array(this.size);
        this.filled = 0;
      }
    }
    return true;
  }
}
registerProcessor('${PROCESSOR}', PcmChunks);
`;

// What the user can do about each way getUserMedia fails (the browser's own words name no remedy).
const MICROPHONE_ERRORS = {
  NotFoundError: 'no microphone found: connect one, or choose one in the browser\'s settings',
  NotAllowedError: 'the microphone is blocked for this page: allow it in the browser\'s site settings',
  NotReadableError: 'the microphone could not be opened: another program may be using it',
  SecurityError: 'the microphone needs a secure page: open it over https, or as localhost',
};

/**
 * Open the microphone on `context` (asks the user's permission). The handle's `start(onchunk)`
 * calls `onchunk(pcm, time)` for every `chunkSeconds` of audio: an ArrayBuffer of 16-bit
 * little-endian mono PCM at `sampleRate` Hz and the context time (s) of its first sample;
 * `stop()` releases the microphone.
 */
export async function openMicrophone(context, { chunkSeconds = 0.02 } = {}) {
  if (!navigator.mediaDevices || !navigator.mediaDevices.getUserMedia) {
    throw new Error('the microphone needs a secure page: open it over https, or as localhost');
  }
  let media;
  try {
    media = await navigator.mediaDevices.getUserMedia({
      audio: { channelCount: 1, echoCancellation: true, noiseSuppression: true, autoGainControl: true },
    });
  } catch (err) {
    throw new Error(MICROPHONE_ERRORS[err.name] || `the microphone could not be opened (${err.message})`);
  }
  try {
    if (!loaded.has(context)) loaded.set(context, loadWorklet(context));
    await loaded.get(context);
  } catch (err) {
    loaded.delete(context);
    for (const track of media.getTracks()) track.stop();
    throw err;
  }
  const source = context.createMediaStreamSource(media);
  // The node writes silence; it is connected to the destination only so that the graph runs it.
  const node = new AudioWorkletNode(context, PROCESSOR, {
    channelCount: 1,
    channelCountMode: 'explicit',
    outputChannelCount: [1],
    processorOptions: { size: Math.round(chunkSeconds * context.sampleRate) },
  });
  return {
    sampleRate: context.sampleRate,
    start(onchunk) {
      node.port.onmessage = (event) => onchunk(event.data.pcm, event.data.time);
      source.connect(node);
      node.connect(context.destination);
    },
    stop() {
      node.port.onmessage = null;
      source.disconnect();
      node.disconnect();
      for (const track of media.getTracks()) track.stop();
    },
  };
}

async function loadWorklet(context) {
  const url = URL.createObjectURL(new Blob([WORKLET], { type: 'text/javascript' }));
  try {
    await context.audioWorklet.addModule(url);
  } finally {
    URL.revokeObjectURL(url);
  }
}
