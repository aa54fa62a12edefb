import { api } from "../api.js";
import { pageReady, say } from "../shell.js";

const form = document.getElementById("login");
const message = document.getElementById("login-message");

function nextPage() {
  const next = new URLSearchParams(location.search).get("next") || "/";
  return next.startsWith("/") && !next.startsWith("//") ? next : "/"; // never leave the site
}

form.addEventListener("submit", async (event) => {
  event.preventDefault();
  const username = form.username.value.trim();
  const password = form.password.value;
  if (!username || !password) return say(message, "Enter your username and your password.", "error");
  document.getElementById("submit").disabled = true;
  try {
    await api("/auth/login", { method: "POST", json: { username, password }, quiet401: true });
    location.assign(nextPage());
  } catch (error) {
    say(message, error.status === 401 ? "Wrong username or password. Check both and try again." : error.message, "error");
    document.getElementById("submit").disabled = false;
    form.password.focus();
  }
});
pageReady(); // first: an inert field cannot take focus
form.username.focus();
