"""PNG decoding to grey: aslam's decoder against OpenCV's ``IMREAD_GRAYSCALE``, in one run.

The reference is OpenCV alone (``cv2.imdecode``, what ``bench/floor.py`` decodes with); aslam's is
``aslam.data_formats.images.png_gray`` (imagecodecs' libpng and libpng's grey weights). Both decode
every image of a recording, alternating rounds, on one thread and on two (the estimate's reader
decodes on two); every grey image is checked to be the same array.

    python bench/decode_bench.py RECORDING.mcap [--rounds 5]

Prints milliseconds per image (median over the rounds) and the ratio aslam ÷ OpenCV.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from aslam.data_formats.images import png_gray


def opencv_gray(data: bytes) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)


def per_image_ms(decode, images: list[bytes], threads: int) -> float:
    with ThreadPoolExecutor(threads) as pool:
        start = time.perf_counter()
        for _ in pool.map(decode, images):
            pass
        return (time.perf_counter() - start) / len(images) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--topic", default="/camera/image/compressed")
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    cv2.setNumThreads(1)  # decoding is one image per thread in both
    with open(args.recording, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        images = [bytes(msg.data) for *_, msg in reader.iter_decoded_messages(topics=[args.topic])]
    for data in images:
        ours = png_gray(data)
        if ours is None or not np.array_equal(ours, opencv_gray(data)):
            raise SystemExit("an image decoded differently (or not by the fast path)")
    result: dict[str, float | int] = {"images": len(images)}
    for threads in (1, 2):
        times: dict[str, list[float]] = {"opencv": [], "aslam": []}
        for _ in range(args.rounds):
            times["opencv"].append(per_image_ms(opencv_gray, images, threads))
            times["aslam"].append(per_image_ms(png_gray, images, threads))
        opencv, ours = statistics.median(times["opencv"]), statistics.median(times["aslam"])
        result |= {
            f"opencv_ms_{threads}_threads": opencv,
            f"aslam_ms_{threads}_threads": ours,
            f"ratio_{threads}_threads": ours / opencv,
        }
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
