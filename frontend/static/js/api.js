// Talking to the varbot API: the session cookie goes along by itself; writes carry the CSRF token.

export const API = "/api/v1";

export class ApiError extends Error {
  constructor(status, detail) {
    super(describeDetail(detail) || `the server answered ${status}`);
    this.status = status;
    this.detail = detail;
  }
}

/** FastAPI errors are a string, or a list of {loc, msg, type, ctx} for invalid input: say either in plain words. */
export function describeDetail(detail) {
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) return detail.map(plainIssue).join(" ");
  return detail ? JSON.stringify(detail) : "";
}

// What each field is called on the pages, and what a valid value looks like where a pattern decides.
const FIELD_NAMES = { username: "The username", password: "The password", new_password: "The new password",
  display_name: "The name", name: "The name", role: "The role", kind: "The kind", count: "The number" };
const PATTERN_RULES = {
  username: "may hold only lower-case letters, digits, dots, dashes and underscores, and must start with a letter or a digit",
};

/** One validation issue as a sentence, e.g. "The username must be at least 3 characters long." */
export function plainIssue(item) {
  const field = (item.loc || []).filter((p) => p !== "body" && p !== "query" && p !== "path").pop();
  const subject = FIELD_NAMES[field] || (field ? `The ${String(field).replaceAll("_", " ")}` : "This value");
  const ctx = item.ctx || {};
  const sentences = {
    missing: `${subject} is missing: fill it in.`,
    string_too_short: ctx.min_length > 1 ? `${subject} must be at least ${ctx.min_length} characters long.` : `${subject} cannot be empty.`,
    string_too_long: `${subject} can be at most ${ctx.max_length} characters long.`,
    string_pattern_mismatch: `${subject} ${PATTERN_RULES[field] || "has characters that are not allowed"}.`,
    enum: `${subject} must be one of: ${ctx.expected || "the choices offered"}.`,
    greater_than_equal: `${subject} must be at least ${ctx.ge}.`,
    less_than_equal: `${subject} can be at most ${ctx.le}.`,
    int_parsing: `${subject} must be a whole number.`,
  };
  return sentences[item.type] || `${subject}: ${item.msg}.`;
}

export function csrfToken() {
  const match = document.cookie.match(/(?:^|;\s*)varbot_csrf=([^;]+)/);
  return match ? decodeURIComponent(match[1]) : "";
}

function goToSignIn() {
  if (location.pathname !== "/login") {
    location.assign(`/login?next=${encodeURIComponent(location.pathname + location.search)}`);
  }
}

export async function api(path, { method = "GET", json, form, quiet401 = false } = {}) {
  const headers = { Accept: "application/json" };
  let body;
  if (json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(json);
  } else if (form !== undefined) {
    body = form;
  }
  if (method !== "GET" && method !== "HEAD") headers["X-CSRF-Token"] = csrfToken();
  const response = await fetch(API + path, { method, headers, body, credentials: "same-origin" });
  if (response.status === 401 && !quiet401) goToSignIn();
  if (response.status === 204) return null;
  const text = await response.text();
  let data = null;
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    data = { detail: text };
  }
  if (!response.ok) throw new ApiError(response.status, data && data.detail);
  return data;
}

/** Multipart upload with progress (fetch cannot report upload progress; XMLHttpRequest can). */
export function uploadWithProgress(path, formData, onProgress) {
  return new Promise((resolve, reject) => {
    const request = new XMLHttpRequest();
    request.open("POST", API + path);
    request.setRequestHeader("X-CSRF-Token", csrfToken());
    request.setRequestHeader("Accept", "application/json");
    request.upload.addEventListener("progress", (event) => {
      if (event.lengthComputable) onProgress(event.loaded / event.total);
    });
    request.addEventListener("load", () => {
      let data = null;
      try {
        data = JSON.parse(request.responseText);
      } catch {
        data = { detail: request.responseText };
      }
      if (request.status === 401) goToSignIn();
      if (request.status >= 200 && request.status < 300) resolve(data);
      else reject(new ApiError(request.status, data && data.detail));
    });
    request.addEventListener("error", () => reject(new ApiError(0, "the upload failed: check your connection and try again")));
    request.send(formData);
  });
}
