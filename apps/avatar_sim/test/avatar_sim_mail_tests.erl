%% The notifier's e-mail and SMS files, parsed back; the camera's PNG files, decoded back.
-module(avatar_sim_mail_tests).
-include_lib("eunit/include/eunit.hrl").

email(Overrides) ->
    maps:merge(#{from => <<"home@example">>, to => <<"me@example">>, subject => <<"INTRUSION">>,
                 body => <<"Someone is in the hall.\nPhotos attached.">>,
                 date => 1731690153000, utc_offset => 0, message_id => <<"42@example">>,
                 attachments => []}, Overrides).

%% Headers, the multipart structure and both attachments come back exactly.
email_round_trip_test() ->
    P1 = avatar_sim_png:photo(<<"hall">>, false, [<<"intruder">>], 1000),
    P2 = crypto:strong_rand_bytes(3000),
    Eml = avatar_sim_mail:email(email(#{attachments => [{<<"photo-0001.png">>, <<"image/png">>, P1},
                                                        {<<"photo-0002.png">>, <<"image/png">>, P2}]})),
    {Headers, Body} = split_message(Eml),
    ?assertEqual(<<"INTRUSION">>, header(<<"subject">>, Headers)),
    ?assertEqual(<<"me@example">>, header(<<"to">>, Headers)),
    ?assertEqual(<<"Fri, 15 Nov 2024 17:02:33 +0000">>, header(<<"date">>, Headers)),
    ?assertEqual(<<"1.0">>, header(<<"mime-version">>, Headers)),
    <<"multipart/mixed; boundary=\"", Rest/binary>> = header(<<"content-type">>, Headers),
    [Boundary, <<>>] = binary:split(Rest, <<"\"">>),
    ?assert(byte_size(Boundary) =< 70),
    [Text, A1, A2] = parts(Body, Boundary),
    {TH, TB} = split_message(Text),
    ?assertEqual(<<"text/plain; charset=utf-8">>, header(<<"content-type">>, TH)),
    ?assertEqual(<<"Someone is in the hall.\nPhotos attached.">>, base64:decode(strip(TB))),
    {H1, B1} = split_message(A1),
    ?assertEqual(<<"attachment; filename=\"photo-0001.png\"">>,
                 header(<<"content-disposition">>, H1)),
    ?assertEqual(<<"base64">>, header(<<"content-transfer-encoding">>, H1)),
    ?assertEqual(P1, base64:decode(strip(B1))),
    {_, B2} = split_message(A2),
    ?assertEqual(P2, base64:decode(strip(B2))),
    %% RFC 5322 line limits, and CRLF everywhere.
    Lines = binary:split(Eml, <<"\r\n">>, [global]),
    ?assert(lists:all(fun(L) -> byte_size(L) =< 998 end, Lines)),
    ?assertEqual(nomatch, binary:match(binary:replace(Eml, <<"\r\n">>, <<>>, [global]), <<"\n">>)),
    ?assert(lists:all(fun(L) -> byte_size(L) =< 76 end, binary:split(strip_keep(B1), <<"\r\n">>, [global]))).

%% Line breaks in a subject from a request cannot add headers; non-ASCII is an encoded word.
header_injection_test() ->
    Eml = avatar_sim_mail:email(email(#{subject => <<"hi\r\nBcc: evil@example">>})),
    {Headers, _} = split_message(Eml),
    ?assertEqual(undefined, header(<<"bcc">>, Headers)),
    Eml2 = avatar_sim_mail:email(email(#{subject => <<"caf", 16#c3, 16#a9>>})),
    {Headers2, _} = split_message(Eml2),
    ?assertEqual(<<"=?UTF-8?B?", (base64:encode(<<"caf", 16#c3, 16#a9>>))/binary, "?=">>,
                 header(<<"subject">>, Headers2)).

%% Dates carry the local offset.
date_offset_test() ->
    ?assertEqual(<<"Fri, 15 Nov 2024 19:02:33 +0200">>,
                 avatar_sim_mail:rfc5322_date(1731690153000, 120)).

%% An SMS file holds its recipient, date and text.
sms_test() ->
    Sms = avatar_sim_mail:sms(#{to => <<"+44">>, text => <<"INTRUSION">>, date => 0, utc_offset => 0}),
    ?assertEqual(<<"To: +44\r\nDate: Thu, 01 Jan 1970 00:00:00 +0000\r\n\r\nINTRUSION\r\n">>, Sms).

%% A photo is a valid PNG: signature, IHDR, chunk CRCs, and pixel data of the right size.
png_is_valid_test() ->
    Png = avatar_sim_png:photo(<<"living">>, true, [<<"resident">>, <<"intruder">>], 123456),
    <<137, $P, $N, $G, 13, 10, 26, 10, Chunks/binary>> = Png,
    [{<<"IHDR">>, <<64:32, 48:32, 8, 2, 0, 0, 0>>}, {<<"IDAT">>, Z}, {<<"IEND">>, <<>>}] = chunks(Chunks),
    Raw = zlib:uncompress(Z),
    ?assertEqual(48 * (1 + 64 * 3), byte_size(Raw)),
    %% Different scenes give different pictures.
    ?assertNotEqual(Png, avatar_sim_png:photo(<<"living">>, false, [], 123456)).

chunks(<<>>) -> [];
chunks(<<Len:32, Type:4/binary, Data:Len/binary, Crc:32, Rest/binary>>) ->
    ?assertEqual(Crc, erlang:crc32([Type, Data])),
    [{Type, Data} | chunks(Rest)].

%% A small MIME reader, enough for these messages.
split_message(Bin) ->
    [Head, Body] = binary:split(Bin, <<"\r\n\r\n">>),
    Headers = [begin
                   [K, V] = binary:split(L, <<": ">>),
                   {string:lowercase(K), V}
               end || L <- binary:split(Head, <<"\r\n">>, [global])],
    {Headers, Body}.

header(Name, Headers) -> proplists:get_value(Name, Headers).

parts(Body, Boundary) ->
    [_Preamble | Rest] = binary:split(Body, <<"--", Boundary/binary, "\r\n">>, [global]),
    {Init, [Last]} = lists:split(length(Rest) - 1, Rest),
    [LastPart, Epilogue] = binary:split(Last, <<"--", Boundary/binary, "--\r\n">>),
    ?assertEqual(<<>>, Epilogue),
    Init ++ [LastPart].

strip(B) -> binary:replace(B, <<"\r\n">>, <<>>, [global]).
strip_keep(B) -> string:trim(B, trailing, "\r\n").
