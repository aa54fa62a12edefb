// Microphone capture with Web Audio (AudioWorklet): raw Float32 samples, a live level, and a WAV at the end.
import { encodeWav, loudness } from "./wav.js";

export class MicrophoneError extends Error {
  constructor(kind, message) {
    super(message);
    this.kind = kind; // "denied" | "no-device" | "unsupported" | "busy"
  }
}

export function explainMicrophoneError(error) {
  const name = error && error.name;
  if (name === "NotAllowedError" || name === "SecurityError") {
    return new MicrophoneError(
      "denied",
      "The browser is not allowed to use your microphone. Click the lock or microphone icon next to the address, " +
        "allow the microphone for this site, then press “Try the microphone again”. You can also upload a WAV file below.",
    );
  }
  if (name === "NotFoundError" || name === "OverconstrainedError") {
    return new MicrophoneError(
      "no-device",
      "No microphone was found. Plug in a headset or microphone and press “Try the microphone again”, " +
        "or upload a WAV file recorded on another device below.",
    );
  }
  if (name === "NotReadableError" || name === "AbortError") {
    return new MicrophoneError(
      "busy",
      "Your microphone is in use by another program or could not be started. Close the other program, then try again.",
    );
  }
  return new MicrophoneError("unsupported", `The microphone could not be started (${name || error}). Try another browser, or upload a WAV file below.`);
}

export class Recorder {
  constructor(onLevel) {
    this.onLevel = onLevel;
    this.context = null;
    this.stream = null;
    this.node = null;
    this.source = null;
    this.chunks = [];
    this.recording = false;
  }

  /** Asks for the microphone once; throws a MicrophoneError with a plain-language message. */
  async open() {
    if (this.context) return;
    if (!navigator.mediaDevices || !navigator.mediaDevices.getUserMedia) {
      throw new MicrophoneError("unsupported", "This browser cannot record audio here. Open the page over https or on localhost, or upload a WAV file below.");
    }
    try {
      this.stream = await navigator.mediaDevices.getUserMedia({
        audio: { echoCancellation: false, noiseSuppression: false, autoGainControl: true, channelCount: 1 },
      });
    } catch (error) {
      throw explainMicrophoneError(error);
    }
    this.context = new AudioContext();
    await this.context.audioWorklet.addModule("/static/js/capture-worklet.js");
    this.source = this.context.createMediaStreamSource(this.stream);
    this.node = new AudioWorkletNode(this.context, "varbot-capture");
    this.node.port.onmessage = (event) => this.#take(event.data);
    this.source.connect(this.node);
  }

  #take(block) {
    const { peak } = loudness(block);
    this.onLevel(Math.min(1, peak * 1.4));
    if (this.recording) this.chunks.push(block);
  }

  async start() {
    await this.open();
    if (this.context.state === "suspended") await this.context.resume();
    this.chunks = [];
    this.recording = true;
  }

  /** Stops and returns {wav, seconds, peak, rms, samples}. */
  stop() {
    this.recording = false;
    const total = this.chunks.reduce((n, c) => n + c.length, 0);
    const samples = new Float32Array(total);
    let offset = 0;
    for (const chunk of this.chunks) {
      samples.set(chunk, offset);
      offset += chunk.length;
    }
    this.chunks = [];
    const rate = this.context.sampleRate;
    return { wav: encodeWav(samples, rate), seconds: total / rate, ...loudness(samples), samples };
  }

  close() {
    if (this.stream) this.stream.getTracks().forEach((track) => track.stop());
    if (this.context) this.context.close();
    this.context = null;
    this.stream = null;
  }
}

/** A press-and-hold button: `begin` while it is held down (the pointer stays with it), `finish` when let go. */
export function onHold(button, begin, finish) {
  button.addEventListener("pointerdown", (event) => {
    button.setPointerCapture(event.pointerId);
    begin();
  });
  button.addEventListener("pointerup", finish);
  button.addEventListener("pointercancel", finish);
  button.addEventListener("contextmenu", (event) => event.preventDefault());
}
