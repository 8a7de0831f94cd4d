// Talking to the service: HTTP calls with the error envelope turned into exceptions, and the
// /v1/stream WebSocket with binary frames decoded by the layout the hello message declares.
// URLs are relative to the page (/viewer/), so the viewer also works behind a path prefix.

export class ApiError extends Error {
  constructor(status, code, message) {
    super(`${code}: ${message}`);
    this.status = status;
    this.code = code;
  }
}

const KEY_STORAGE = "rsmt-viewer-api-key";

export class Api {
  constructor(base = new URL("../", window.location.href)) {
    this.base = base;
    // Session storage: the key survives a reload but not the browser, and never leaves this origin.
    this.key = window.sessionStorage.getItem(KEY_STORAGE) || "";
  }

  setKey(key) {
    this.key = key.trim();
    if (this.key) window.sessionStorage.setItem(KEY_STORAGE, this.key);
    else window.sessionStorage.removeItem(KEY_STORAGE);
  }

  url(path) { return new URL(path, this.base); }

  async request(method, path, body) {
    const headers = {};
    if (body !== undefined) headers["content-type"] = "application/json";
    if (this.key) headers["x-api-key"] = this.key;
    let res;
    try {
      res = await fetch(this.url(path), { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
    } catch (err) {
      throw new ApiError(0, "network", `cannot reach the service (${err.message}); is it running?`);
    }
    if (res.status === 204) return null;
    const text = await res.text();
    let data = null;
    try { data = text ? JSON.parse(text) : null; } catch { /* not JSON: reported below */ }
    if (!res.ok) {
      const e = data && data.error;
      throw new ApiError(res.status, e ? e.code : `http_${res.status}`, e ? e.message : text.slice(0, 200));
    }
    return data;
  }

  get(path) { return this.request("GET", path); }
  post(path, body) { return this.request("POST", path, body); }

  model() { return this.get("v1/model"); }
  rig() { return this.get("v1/viewer/rig"); }
  demos() { return this.get("v1/viewer/demos"); }
  demo(name) { return this.get(`v1/viewer/demos/${encodeURIComponent(name)}`); }
  readTake(name, bvh) { return this.post("v1/viewer/clip", { name, motion: { bvh } }); }
  styles() { return this.get("v1/styles"); }
  registerStyle(name, motion) { return this.post("v1/styles", { name, motion }); }
  transition(body) { return this.post("v1/transition", body); }

  streamUrl(encoding) {
    const u = this.url("v1/stream");
    u.protocol = u.protocol === "https:" ? "wss:" : "ws:";
    u.searchParams.set("encoding", encoding);
    // Browsers cannot set headers on a WebSocket handshake: the key goes in the query (protocol.md).
    if (this.key) u.searchParams.set("token", this.key);
    return u.toString();
  }
}

// One /v1/stream connection. Callbacks: onHello(msg), onFrame(frame), onMessage(msg) for every other
// JSON message, onClose(code, reason). A frame is {slot, seq, t, remaining, root, rots, arrived} with
// `arrived` the performance.now() of its arrival, for latency figures.
export class LiveStream {
  constructor(api, handlers, encoding = "binary") {
    this.api = api;
    this.handlers = handlers;
    this.encoding = encoding;
    this.ws = null;
    this.layout = null;
    this.pings = new Map();
    this.rttMs = null;
    this.pingCount = 0;
  }

  connect() {
    return new Promise((resolve, reject) => {
      const ws = new WebSocket(this.api.streamUrl(this.encoding));
      ws.binaryType = "arraybuffer";
      this.ws = ws;
      let hello = false;
      ws.onmessage = (ev) => {
        const arrived = performance.now();
        if (typeof ev.data !== "string") { this.handlers.onFrame?.(this.decode(ev.data, arrived)); return; }
        const msg = JSON.parse(ev.data);
        if (msg.type === "hello") {
          hello = true;
          this.layout = layoutOffsets(msg.frame_layout);
          this.handlers.onHello?.(msg);
          resolve(msg);
        } else if (msg.type === "frame") {
          const p = msg.pose;
          this.handlers.onFrame?.({ slot: msg.slot, seq: msg.seq, t: msg.t, remaining: msg.remaining, root: p.root_position,
                                    rots: Float32Array.from(p.rotations.flat()), arrived });
        } else if (msg.type === "pong") {
          const sent = this.pings.get(msg.id);
          if (sent !== undefined) { this.rttMs = arrived - sent; this.pings.delete(msg.id); }
          this.handlers.onMessage?.(msg);
        } else {
          this.handlers.onMessage?.(msg);
        }
      };
      ws.onclose = (ev) => {
        this.ws = null;
        if (!hello) reject(new Error(`the stream closed before its hello (code ${ev.code}${ev.reason ? ": " + ev.reason : ""})`));
        this.handlers.onClose?.(ev.code, ev.reason);
      };
      ws.onerror = () => { /* onclose follows with the code */ };
    });
  }

  get open() { return this.ws !== null && this.ws.readyState === WebSocket.OPEN; }

  send(msg) {
    if (!this.open) throw new Error("the stream is not connected");
    this.ws.send(JSON.stringify(msg));
  }

  ping() {
    const id = ++this.pingCount;
    this.pings.set(id, performance.now());
    if (this.pings.size > 8) this.pings.delete(this.pings.keys().next().value); // lost pongs never pile up
    this.send({ type: "ping", id });
  }

  close() { if (this.ws) this.ws.close(1000, "viewer closed the stream"); }

  decode(buffer, arrived) {
    // Little-endian float32 whatever the machine's byte order: read through a DataView.
    const L = this.layout, dv = new DataView(buffer);
    const f = (i) => dv.getFloat32(i * 4, true);
    const rots = new Float32Array(L.rotations.count);
    for (let i = 0; i < rots.length; i++) rots[i] = f(L.rotations.offset + i);
    return { slot: f(L.slot.offset), seq: f(L.seq.offset), t: f(L.t.offset), remaining: f(L.remaining.offset),
             root: [f(L.root_position.offset), f(L.root_position.offset + 1), f(L.root_position.offset + 2)], rots, arrived };
  }
}

function layoutOffsets(layout) {
  const out = {};
  for (const field of layout.fields) out[field.name] = { offset: field.offset, count: field.count };
  return out;
}
