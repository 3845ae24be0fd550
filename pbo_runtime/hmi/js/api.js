// The page's way to the local API: JSON requests and WebSocket streams, all under the token cookie
// the first load set (HttpOnly: this script never sees the token itself).

export class ApiError extends Error {
  constructor(status, reply) {
    super(reply && reply.error ? reply.error : `HTTP ${status}`);
    this.status = status;
    this.reply = reply;
  }
}

async function answer(response) {
  const type = response.headers.get("content-type") || "";
  const body = type.includes("json") ? await response.json() : await response.text();
  if (!response.ok || (body && body.ok === false)) throw new ApiError(response.status, body);
  return body;
}

/** GET /api/PATH: the JSON reply, or an ApiError carrying the reply's one-line `error`. */
export async function get(path, params = {}) {
  const query = new URLSearchParams(Object.entries(params).filter(([, v]) => v !== undefined && v !== null));
  const url = `/api/${path}` + (query.toString() ? `?${query}` : "");
  return answer(await fetch(url, { credentials: "same-origin" }));
}

/** POST /api/PATH with a JSON body (or YAML text when `body` is a string and `type` says so). */
export async function post(path, body = {}, type = "application/json") {
  const payload = typeof body === "string" ? body : JSON.stringify(body);
  return answer(await fetch(`/api/${path}`, { method: "POST", credentials: "same-origin",
                                              headers: { "content-type": type }, body: payload }));
}

/** An operator verb (the CLI's, from the command table): POST /api/verbs/NAME. */
export function verb(name, args = {}) {
  return post(`verbs/${name}`, args);
}

/**
 * A WebSocket stream of /api/streams/PATH: `onMessage(json)` for each message. It reconnects
 * after a second when the run ends or the server restarts; `close()` ends it for good.
 */
export function stream(path, params, onMessage, onState = () => {}) {
  let socket = null;
  let closed = false;
  let retry = null;
  const query = new URLSearchParams(params);
  const open = () => {
    const scheme = location.protocol === "https:" ? "wss" : "ws";
    socket = new WebSocket(`${scheme}://${location.host}/api/streams/${path}?${query}`);
    socket.onopen = () => onState("open");
    socket.onmessage = (event) => onMessage(JSON.parse(event.data));
    socket.onclose = () => {
      onState("closed");
      if (!closed) retry = setTimeout(open, 1000);
    };
  };
  open();
  return { close() { closed = true; clearTimeout(retry); if (socket) socket.close(); } };
}

// The subsystem file changed (a job saved on the canvas, an application or an object saved in the
// workspace): every part that shows what the file holds reads it again.
const FILE_CHANGED = "pbo:file-changed";

export function announceFileChanged() {
  window.dispatchEvent(new Event(FILE_CHANGED));
}

/** Calls `reread` whenever a part of the page changed the file; returns the unsubscribe function. */
export function onFileChanged(reread) {
  window.addEventListener(FILE_CHANGED, reread);
  return () => window.removeEventListener(FILE_CHANGED, reread);
}
