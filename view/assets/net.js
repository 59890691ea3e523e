// The WebSocket connection to the `blueshift view` server (PROTOCOL.md): JSON text messages
// both ways, binary frames from the server (u32 LE header length, JSON header, PNG).

/** Splits a binary frame into its JSON header and the PNG as a Blob. */
export function parseFrame(buf) {
  const view = new DataView(buf);
  const n = view.getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  const png = new Blob([new Uint8Array(buf, 4 + n)], { type: 'image/png' });
  return { header, png };
}

/**
 * One connection. `onMessage(msg)` gets each JSON message, `onFrame(header, png)` each
 * binary frame, `onState(state)` 'connecting' | 'open' | 'closed'.
 */
export class Connection {
  constructor({ onMessage, onFrame, onState }) {
    this.onMessage = onMessage;
    this.onFrame = onFrame;
    this.onState = onState;
    this.ws = null;
  }

  connect() {
    if (this.ws && this.ws.readyState <= WebSocket.OPEN) return;
    // The server checks Host and Origin: build the URL from the page's own location.
    const url = new URL('ws', location.href);
    url.protocol = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const ws = new WebSocket(url);
    ws.binaryType = 'arraybuffer';
    this.ws = ws;
    this.onState('connecting');
    ws.onopen = () => this.onState('open');
    ws.onclose = () => {
      if (this.ws === ws) this.onState('closed');
    };
    ws.onmessage = (ev) => {
      if (typeof ev.data === 'string') {
        let msg;
        try {
          msg = JSON.parse(ev.data);
        } catch (e) {
          this.onMessage({ type: 'error', message: `unreadable server message: ${e}` });
          return;
        }
        this.onMessage(msg);
      } else {
        let frame;
        try {
          frame = parseFrame(ev.data);
        } catch (e) {
          this.onMessage({ type: 'error', message: `unreadable frame: ${e}` });
          return;
        }
        this.onFrame(frame.header, frame.png);
      }
    };
  }

  get open() {
    return this.ws !== null && this.ws.readyState === WebSocket.OPEN;
  }

  /** Sends one message; returns false (and sends nothing) while the socket is not open. */
  send(obj) {
    if (!this.open) return false;
    this.ws.send(JSON.stringify(obj));
    return true;
  }
}

/**
 * Coalesces a stream of messages to at most one per animation frame: `push(obj)` replaces
 * the pending message (or, with `merge`, adds its fields to it: for partial updates such as
 * `settings`), the newest is sent on the next frame. `flush()` sends it now.
 */
export class Throttle {
  constructor(send, { merge = false } = {}) {
    this.sendFn = send;
    this.merge = merge;
    this.pending = null;
    this.scheduled = false;
  }
  push(obj) {
    this.pending = this.merge && this.pending ? { ...this.pending, ...obj } : obj;
    if (!this.scheduled) {
      this.scheduled = true;
      requestAnimationFrame(() => {
        this.scheduled = false;
        this.flush();
      });
    }
  }
  flush() {
    if (this.pending !== null) {
      const msg = this.pending;
      this.pending = null;
      this.sendFn(msg);
    }
  }
}
