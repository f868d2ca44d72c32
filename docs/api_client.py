"""Subscribe to a live kinefuse server's fused frames (docs/api.md). Needs only aiohttp.

KINEFUSE_TOKEN=SECRET python api_client.py ws://127.0.0.1:7401/api/v1/stream --frames 90
"""

import argparse
import asyncio
import hashlib
import hmac
import json
import os

import aiohttp


async def main(url: str, frames: int) -> None:
    async with aiohttp.ClientSession() as http, http.ws_connect(url + "?format=json") as ws:
        hello = await ws.receive_json()
        if hello["auth"] == "hmac-sha256":  # prove the token without sending it
            msg = f"{hello['api']}/{hello['version']}|{hello['nonce']}".encode()
            mac = hmac.new(os.environ["KINEFUSE_TOKEN"].encode(), msg, hashlib.sha256)
            await ws.send_json({"type": "auth", "mac": mac.hexdigest()})
        welcome = await ws.receive_json()
        if welcome["type"] != "welcome":
            raise SystemExit(f"refused: {welcome.get('error')}")
        joints, n = welcome["joints"], 0
        async for m in ws:
            item = json.loads(m.data)
            if item["type"] == "status":
                print("sensors:", {s["id"]: s["connected"] for s in item["sensors"]})
            elif item["type"] == "frame":
                head = item["positions_m"][joints.index("Head")]
                print(f"frame {item['seq']} t={item['t_server_s']:.3f} s head={head}")
                n += 1
                if n >= frames:
                    break


if __name__ == "__main__":
    p = argparse.ArgumentParser()
    p.add_argument("url")
    p.add_argument("--frames", type=int, default=90)
    a = p.parse_args()
    asyncio.run(main(a.url, a.frames))
