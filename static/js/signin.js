import { checkKey, rememberKey } from "./api.js";
import { errorBox, h, params } from "./ui.js";

const message = document.getElementById("message");
const reason = params().get("reason");
if (reason) message.append(h("div", { class: "notice" }, reason));

document.getElementById("signin").addEventListener("submit", async (e) => {
  e.preventDefault();
  const key = document.getElementById("key").value.trim();
  const button = e.target.querySelector("button");
  button.disabled = true;
  message.replaceChildren();
  try {
    const me = await checkKey(key);
    rememberKey(key, me);
    const next = params().get("next");
    location.assign(next && next.startsWith("/") && !next.startsWith("//") ? next : "/");
  } catch (err) {
    message.replaceChildren(errorBox(err, err.status === 401 ? "Sign-in failed" : "Sign-in not possible"));
  } finally {
    button.disabled = false;
  }
});
