"""The floor of an estimate, sharing no code with aslam: read, decode, gradients, histogram.

One process, one thread: the mcap reader with the ROS 2 CDR decoder, ``cv2.imdecode`` to grey,
``cv2.Sobel`` in x and y, and a 32-bin magnitude-weighted orientation histogram per image. Nothing
is kept, nothing is written. Whatever ``aslam estimate`` costs beyond this (its pipeline, the
SLAM, writing the estimate file, hashing the recording) is its own overhead.

    python bench/floor.py RECORDING.mcap [--topic /camera/image/compressed]

Prints one JSON object: images, seconds (from the first import of the work to the last histogram).
"""

import argparse
import json
import time

BINS = 32


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("recording")
    parser.add_argument("--topic", default="/camera/image/compressed")
    args = parser.parse_args()
    start = time.perf_counter()
    import cv2
    import numpy as np
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    images = 0
    checksum = 0.0
    with open(args.recording, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, _channel, _message, msg in reader.iter_decoded_messages(topics=[args.topic]):
            gray = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_GRAYSCALE)
            dx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
            dy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
            magnitude, angle = cv2.cartToPolar(dx, dy)  # angle in [0, 2π)
            bins = np.minimum((angle * (BINS / (2 * np.pi))).astype(np.int32), BINS - 1)
            histogram = np.bincount(bins.ravel(), weights=magnitude.ravel(), minlength=BINS)
            checksum += float(histogram[0] / max(histogram.sum(), 1e-12))
            images += 1
    print(json.dumps({"images": images, "seconds": time.perf_counter() - start, "checksum": checksum}))


if __name__ == "__main__":
    main()
