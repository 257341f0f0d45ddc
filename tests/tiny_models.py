"""Tiny randomly initialised models with the real architectures and processors, saved like hub checkpoints:
the loading and inference code of trackingworld.priors runs on them offline (nothing is downloaded)."""

from pathlib import Path

import transformers as tf


def depth_anything(out: Path, metric: bool = False) -> Path:
    bb = tf.Dinov2Config(hidden_size=32, num_hidden_layers=4, num_attention_heads=2, intermediate_size=64,
                         image_size=56, patch_size=14, out_features=["stage1", "stage2", "stage3", "stage4"],
                         reshape_hidden_states=False)
    extra = {"depth_estimation_type": "metric", "max_depth": 20} if metric else {}
    cfg = tf.DepthAnythingConfig(backbone_config=bb, neck_hidden_sizes=[16, 32, 32, 32], fusion_hidden_size=16,
                                 head_hidden_size=8, reassemble_hidden_size=32, patch_size=14, **extra)
    tf.DepthAnythingForDepthEstimation(cfg).save_pretrained(out)
    proc = tf.DPTImageProcessor(size={"height": 56, "width": 56}, keep_aspect_ratio=True, ensure_multiple_of=14)
    proc.save_pretrained(out)
    return out


def grounding_dino(out: Path) -> Path:
    vocab = ["[PAD]", "[UNK]", "[CLS]", "[SEP]", "[MASK]", ".", "dog", "person", "car", "animal", "cat"]
    out.mkdir(parents=True, exist_ok=True)
    (out / "vocab.txt").write_text("\n".join(vocab) + "\n")
    tok = tf.BertTokenizer(str(out / "vocab.txt"))
    swin = tf.SwinConfig(embed_dim=16, depths=[1, 1, 1, 1], num_heads=[1, 1, 1, 1], window_size=4, image_size=64,
                         out_features=["stage2", "stage3", "stage4"])
    bert = tf.BertConfig(vocab_size=len(vocab), hidden_size=16, num_hidden_layers=1, num_attention_heads=2,
                         intermediate_size=32, max_position_embeddings=64)
    cfg = tf.GroundingDinoConfig(backbone_config=swin, text_config=bert, d_model=32, encoder_layers=1,
                                 decoder_layers=2, encoder_ffn_dim=32, decoder_ffn_dim=32, encoder_attention_heads=2,
                                 decoder_attention_heads=2, num_queries=10, num_feature_levels=3,
                                 encoder_n_points=2, decoder_n_points=2, use_timm_backbone=False)
    tf.GroundingDinoForObjectDetection(cfg).save_pretrained(out)
    ip = tf.GroundingDinoImageProcessor(size={"shortest_edge": 64, "longest_edge": 96})
    tf.GroundingDinoProcessor(image_processor=ip, tokenizer=tok).save_pretrained(out)
    return out


def sam(out: Path) -> Path:
    vc = tf.SamVisionConfig(hidden_size=16, num_hidden_layers=1, num_attention_heads=2, mlp_dim=32, image_size=64,
                            patch_size=8, output_channels=8, global_attn_indexes=[0], window_size=2,
                            num_pos_feats=4)
    pc = tf.SamPromptEncoderConfig(hidden_size=8, image_size=64, patch_size=8, mask_input_channels=4)
    mc = tf.SamMaskDecoderConfig(hidden_size=8, mlp_dim=16, num_hidden_layers=1, num_attention_heads=2,
                                 iou_head_hidden_dim=8)
    tf.SamModel(tf.SamConfig(vision_config=vc, prompt_encoder_config=pc, mask_decoder_config=mc)).save_pretrained(out)
    ip = tf.SamImageProcessor(size={"longest_edge": 64}, pad_size={"height": 64, "width": 64})
    tf.SamProcessor(image_processor=ip).save_pretrained(out)
    return out



def zoedepth(out: Path) -> Path:
    bb = tf.BeitConfig(hidden_size=32, num_hidden_layers=4, num_attention_heads=2, intermediate_size=64,
                       image_size=64, patch_size=16, out_features=["stage1", "stage2", "stage3", "stage4"],
                       reshape_hidden_states=False, use_relative_position_bias=True)
    cfg = tf.ZoeDepthConfig(backbone_config=bb, neck_hidden_sizes=[16, 32, 32, 32], fusion_hidden_size=16,
                            reassemble_factors=[4, 2, 1, 0.5], bottleneck_features=16, num_relative_features=8,
                            bin_embedding_dim=16, backbone_hidden_size=32,
                            bin_configurations=[{"n_bins": 8, "min_depth": 0.001, "max_depth": 10.0, "name": "nyu"}])
    tf.ZoeDepthForDepthEstimation(cfg).save_pretrained(out)
    tf.ZoeDepthImageProcessor(size={"height": 64, "width": 64}, keep_aspect_ratio=True,
                              ensure_multiple_of=16).save_pretrained(out)
    return out


def depth_pro(out: Path, fov_deg: float = 50.0) -> Path:
    """A tiny Depth Pro whose field-of-view head always says ``fov_deg`` (weights zero, bias the answer). Its
    processor config is written as JSON: DepthProImageProcessor itself cannot be built without torchvision."""
    import json

    import torch

    def dino():
        return {"model_type": "dinov2", "hidden_size": 16, "num_hidden_layers": 2, "num_attention_heads": 2,
                "intermediate_size": 32, "image_size": 32, "patch_size": 8}

    cfg = tf.DepthProConfig(fusion_hidden_size=16, patch_size=32, intermediate_hook_ids=[1, 0],
                            intermediate_feature_dims=[16, 16], scaled_images_ratios=[0.5, 1],
                            scaled_images_overlap_ratios=[0.0, 0.25], scaled_images_feature_dims=[16, 16],
                            merge_padding_value=1, use_fov_model=True, num_fov_head_layers=1,
                            image_model_config=dino(), patch_model_config=dino(), fov_model_config=dino())
    model = tf.DepthProForDepthEstimation(cfg)
    last = model.fov_model.head.layers[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.fill_(fov_deg)
    model.save_pretrained(out)
    (out / "preprocessor_config.json").write_text(json.dumps({
        "image_processor_type": "DepthProImageProcessor", "size": {"height": 64, "width": 64},
        "image_mean": [0.5] * 3, "image_std": [0.5] * 3, "rescale_factor": 1 / 255, "do_resize": True,
        "do_rescale": True, "do_normalize": True, "resample": 2}))
    return out
